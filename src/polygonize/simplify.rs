//! Simplification of the `polygonize` stage: topology-safe half-edge collapses that remove the
//! short edges and slivers marching tetrahedra makes.
//!
//! Input: the marching-tetrahedra mesh as triangles over the crossed lattice edges, a position
//! per vertex (the linear interpolation of the end values on its lattice edge, which costs no
//! evaluation), a local cell size per vertex and the vertices pinned (frozen: never removed,
//! never moved onto, their triangles unchanged; step 5's local fallback). Output: which vertices survive, the
//! surviving triangles (in the input's order, indices still the input's), and the caller's
//! per-vertex work (vertex placement) on the survivors, run as soon as each is known to survive.
//!
//! Invariants: the output is a 2-manifold of the same topology as the input (same components,
//! Euler characteristic and boundary), wound consistently, and its vertices are a subset of the
//! input's, so they stay on their lattice edges and are projected onto the zero set afterwards
//! exactly like before; vertices on the mesh boundary (the region's faces) are never removed and
//! never moved. The work is split into fixed chunks of vertices and then one sequential sweep
//! (see [`simplify_chunked`]), so the result does not depend on the thread count.
//!
//! # Why a half-edge collapse keeps the guarantees
//!
//! Collapsing the edge uv by moving u onto v deletes the two triangles around uv and replaces u
//! by v in the others. On a closed 2-manifold, this preserves the topology exactly when the
//! *link condition* holds: the vertices adjacent to both u and v are only the two opposite
//! vertices w₁, w₂ of the deleted triangles, and the edge w₁w₂ is not in both links (Dey,
//! Edelsbrunner, Guha & Nekhayev, *Topology preserving edge contraction*, Publ. Inst. Math. 1999;
//! Hoppe et al., *Mesh optimization*, SIGGRAPH 1993). We also refuse to lower the valence of w₁
//! or w₂ below 3 (which would collapse a tetrahedron-shaped component), and only remove u whose
//! link is one closed cycle (an interior vertex), so the region's boundary is untouched. Every
//! surviving triangle keeps its cyclic order, so the winding stays consistent; triangles are
//! never created across octree leaves' shared faces in a way that could open a crack, because
//! the mesh is already welded (one vertex per lattice edge) and collapses only merge vertices.
//!
//! Geometric checks keep the shape: a collapse is refused when a moved triangle's normal turns
//! by more than [`MAX_NORMAL_TURN_COS`]'s angle, when a new edge is longer than
//! [`MAX_EDGE`] local cells (this bounds the distance between the mesh and the surface), or when
//! it would make the worst triangle shape around u worse than both [`GOOD_QUALITY`] and what it
//! was. The targets v are tried nearest first: the first one that leaves every triangle around
//! it well shaped wins, else the valid one with the best worst shape.
//!
//! Order: vertices are renumbered by first use in the triangle list (leaf by leaf in the
//! octree's depth-first order) and visited in blocks of [`ORDER_BLOCK`] consecutive numbers,
//! which are close in space, so the sweep stays in cache (visiting them by one global ranking,
//! or in lattice-edge order, was several times slower for cache misses); inside a block by increasing shortest-edge length relative to their cell (ties by
//! index), and only those whose shortest edge is below [`SHORT_EDGE`] cells are candidates:
//! these are the vertices marching tetrahedra puts next to a lattice point or next to each other
//! on a cell's face and body diagonals.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::vec3::{cross, dot, sub};

/// Largest length of a new edge, in local cell sizes.
const MAX_EDGE: f64 = 1.2;

/// A vertex is a candidate when its shortest edge is below this many local cell sizes.
const SHORT_EDGE: f64 = 0.6;

/// Squared mean ratio (see [`shape`]) above which a triangle counts as well shaped (mean ratio
/// 0.6).
const GOOD_QUALITY: f64 = 0.36;

/// Cosine of the largest turn of a moved triangle's normal (about 40°).
pub(crate) const MAX_NORMAL_TURN_COS: f64 = 0.75;

/// Vertices per chunk of the parallel pass (fixed, so the result never depends on the thread
/// count).
const CHUNK: usize = 65536;

/// Triangles per block of the parallel renumbering and partition (any fixed size gives the same
/// result; this one gives tens of tasks for the meshes here).
const RENUMBER_BLOCK: usize = 16384;

/// Vertices per parallel task of the caller's per-vertex work.
const WORK_BLOCK: usize = 1024;

/// Vertices per block of the visiting order.
const ORDER_BLOCK: u32 = 1024;

/// The result: `keep[v]` for each input vertex, the surviving triangles (input indices), and
/// the caller's per-vertex work on each surviving vertex, in increasing vertex order.
pub(crate) struct Simplified<T> {
    pub keep: Vec<bool>,
    pub triangles: Vec<[u32; 3]>,
    pub results: Vec<T>,
}

/// One chunk's part of the parallel pass: its surviving triangles and `keep` (whole-mesh
/// numbers), and the work on its settled vertices (kept, not on the chunk border), in order.
struct ChunkPart<T> {
    keep: Vec<bool>,
    triangles: Vec<[u32; 3]>,
    results: Vec<T>,
}

/// [`simplify_chunked`]'s result: `keep` and the surviving triangles, and the work on every
/// surviving vertex v, found at `lists[slot[v].0][slot[v].1]`.
struct Chunked<T> {
    keep: Vec<bool>,
    triangles: Vec<[u32; 3]>,
    slot: Vec<(u32, u32)>,
    lists: Vec<Vec<T>>,
}

impl<T: Copy> Chunked<T> {
    /// The work's result on the surviving vertex `v`.
    fn result(&self, v: u32) -> T {
        let (list, i) = self.slot[v as usize];
        self.lists[list as usize][i as usize]
    }
}

/// `work` on each vertex of `vertices`, in order, in parallel blocks.
fn work_on<T: Send, W: Fn(u32) -> T + Sync>(vertices: &[u32], work: &W) -> Vec<T> {
    vertices
        .par_chunks(WORK_BLOCK)
        .flat_map_iter(|block| block.iter().map(|&v| work(v)))
        .collect()
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

/// The square of the triangle's mean ratio 2√3·|n| / Σ lᵢ² (1 for equilateral, 0 for
/// degenerate; n = (b − a) × (c − a), twice the area), and n. No square root is taken.
pub(crate) fn shape(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> (f64, [f64; 3]) {
    let (ab, ac, bc) = (sub(b, a), sub(c, a), sub(c, b));
    let n = cross(ab, ac);
    let lengths = dot(ab, ab) + dot(ac, ac) + dot(bc, bc);
    let quality = if lengths > 0.0 {
        12.0 * dot(n, n) / (lengths * lengths)
    } else {
        0.0
    };
    (quality, n)
}

/// Most triangles a vertex's star holds here; a vertex with more is frozen (never removed, never
/// a target, never an opposite vertex w₁, w₂ of a collapse), and a collapse that would give the
/// target more is refused.
const STAR_CAPACITY: usize = 15;

/// The triangles around one vertex, inline (one cache line).
#[derive(Clone, Copy)]
#[repr(align(64))]
struct Star {
    len: u32,
    triangles: [u32; STAR_CAPACITY],
}

impl Star {
    const FROZEN: u32 = u32::MAX;

    fn as_slice(&self) -> &[u32] {
        if self.len == Star::FROZEN {
            return &[];
        }
        &self.triangles[..self.len as usize]
    }

    fn is_frozen(&self) -> bool {
        self.len == Star::FROZEN
    }

    /// Number of triangles (infinite-like for a frozen star).
    fn count(&self) -> usize {
        if self.is_frozen() {
            usize::MAX
        } else {
            self.len as usize
        }
    }

    fn push(&mut self, t: u32) {
        // Callers check the capacity first.
        if let Some(slot) = self.triangles.get_mut(self.len as usize) {
            *slot = t;
            self.len += 1;
        }
    }

    fn remove(&mut self, t: u32) {
        let n = self.len as usize;
        if let Some(k) = self.triangles[..n].iter().position(|&s| s == t) {
            self.triangles[k] = self.triangles[n - 1];
            self.len -= 1;
        }
    }
}

/// One vertex of the link of the vertex u being removed.
#[derive(Clone, Copy)]
struct RingVertex {
    vertex: u32,
    position: [f64; 3],
    /// (a − u) × (b − u) for this vertex a and the next one b of the link.
    normal: [f64; 3],
    /// Squared length of `normal`.
    normal2: f64,
}

/// The mesh with its vertex-to-triangle lists, updated by the collapses.
struct Mesh {
    triangles: Vec<[u32; 3]>,
    alive: Vec<bool>,
    around: Vec<Star>,
}

impl Mesh {
    /// The link of `u` as one closed cycle of neighbours in winding order, or None when u is on
    /// the boundary or its link is not one cycle.
    fn link_cycle(&self, u: u32, cycle: &mut Vec<u32>, edges: &mut Vec<(u32, u32)>) -> bool {
        cycle.clear();
        edges.clear();
        let star = self.around[u as usize].as_slice();
        if star.len() < 3 {
            return false;
        }
        // Link edges a → b of the triangles (u, a, b).
        for &t in star {
            let tri = self.triangles[t as usize];
            let Some(k) = tri.iter().position(|&x| x == u) else {
                return false;
            };
            edges.push((tri[(k + 1) % 3], tri[(k + 2) % 3]));
        }
        let start = edges[0].0;
        let mut current = start;
        for _ in 0..edges.len() {
            let mut next = None;
            for &(a, b) in edges.iter() {
                if a == current {
                    if next.is_some() {
                        return false;
                    }
                    next = Some(b);
                }
            }
            let Some(next) = next else {
                return false;
            };
            cycle.push(current);
            current = next;
            if current == start {
                break;
            }
        }
        current == start && cycle.len() == edges.len()
    }

    /// The worst radius ratio of the triangles around `u` after moving it onto `v`, or None when
    /// the collapse u → v is not allowed. `ring` is u's link (vertex, position, and the normal
    /// (a − u) × (b − u) of the triangle it opens with the next one, with its squared length),
    /// `i` the position of v in it. `mark[x] == stamp` exactly for the vertices x of the link.
    /// The checks are independent (any failing one refuses the collapse), so the cheap in-cache
    /// geometric ones go first (the new edge lengths, then the shapes and normal turns), then
    /// the ones that read the stars of other vertices.
    fn collapse_quality(
        &self,
        ring: &[RingVertex],
        i: usize,
        limit2: f64,
        (mark, stamp): (&[u32], u32),
    ) -> Option<f64> {
        let n = ring.len();
        let v = ring[i].vertex;
        let pv = ring[i].position;
        // The triangles (u, a, b) with a, b ≠ v: k ∉ {i − 1, i}. Their new edges first (no
        // shape is computed for a target that one of them rules out).
        for k in (i + 1)..(i + n - 1) {
            let k = if k >= n { k - n } else { k };
            let d = sub(pv, ring[k].position);
            if dot(d, d) > limit2 {
                return None;
            }
        }
        let mut worst = f64::INFINITY;
        for k in (i + 1)..(i + n - 1) {
            let k = if k >= n { k - n } else { k };
            let (ra, rb) = (&ring[k], &ring[if k + 1 == n { 0 } else { k + 1 }]);
            let (pa, pb) = (ra.position, rb.position);
            let (old, old2) = (ra.normal, ra.normal2);
            let (quality, new) = shape(pv, pa, pb);
            let new2 = dot(new, new);
            if new2.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return None;
            }
            // cos(turn) ≥ MAX_NORMAL_TURN_COS, squared (the cosine must be positive).
            let turn = dot(old, new);
            if old2 > 0.0
                && (turn <= 0.0
                    || turn * turn < MAX_NORMAL_TURN_COS * MAX_NORMAL_TURN_COS * old2 * new2)
            {
                return None;
            }
            worst = worst.min(quality);
        }
        let w1 = ring[(i + n - 1) % n].vertex;
        let w2 = ring[(i + 1) % n].vertex;
        // Valence of w₁, w₂ stays at least 3.
        let (star_v, star_w1, star_w2) = (
            &self.around[v as usize],
            &self.around[w1 as usize],
            &self.around[w2 as usize],
        );
        if star_w1.count() < 4 || star_w2.count() < 4 || star_w1.is_frozen() || star_w2.is_frozen()
        {
            return None;
        }
        // The target keeps its triangles, loses 2 and gains u's others.
        if star_v.is_frozen() || star_v.count() + n - 2 > STAR_CAPACITY {
            return None;
        }
        // Link condition: no common neighbour besides w₁ and w₂, and, for a valence-3 u, no
        // triangle (v, w₁, w₂) already.
        for &t in star_v.as_slice() {
            let tri = self.triangles[t as usize];
            let mut common = 0;
            for x in tri {
                if x == w1 || x == w2 {
                    common += 1;
                } else if x != v && mark[x as usize] == stamp {
                    return None;
                }
            }
            if n == 3 && common == 2 {
                return None;
            }
        }
        Some(worst)
    }

    fn collapse(&mut self, u: u32, v: u32) {
        let star = self.around[u as usize];
        self.around[u as usize].len = 0;
        for &t in star.as_slice() {
            let tri = self.triangles[t as usize];
            if tri.contains(&v) {
                self.alive[t as usize] = false;
                for x in tri {
                    if x != u {
                        self.around[x as usize].remove(t);
                    }
                }
            } else {
                self.triangles[t as usize] = tri.map(|x| if x == u { v } else { x });
                self.around[v as usize].push(t);
            }
        }
    }
}

/// Collapses the short edges of the mesh `triangles` over `positions`; `sizes[v]` is the local
/// cell size at vertex v (input units). `work(v)` is run once on every surviving vertex v (the
/// caller's next step, vertex placement), as soon as v is known to survive: a vertex that no
/// collapse of the sequential pass can remove (every one off the chunk borders) right after its
/// chunk's sweep, in parallel with the other chunks' sweeps; the border vertices in parallel
/// with the sequential pass, ahead of it (the results of those it removes are dropped). So no
/// core waits for a chunk's or the pass's end, and the results do not depend on the
/// scheduling, as long as `work` is a function of v alone.
pub(crate) fn simplify<T, W>(
    positions: &[[f64; 3]],
    sizes: &[f64],
    triangles: Vec<[u32; 3]>,
    pinned: &[bool],
    work: &W,
) -> Simplified<T>
where
    T: Copy + Send + Sync,
    W: Fn(u32) -> T + Sync,
{
    // Renumber the vertices by first use in the triangles (which come leaf by leaf in the
    // octree's depth-first order), so that a vertex, its triangles and its neighbours sit close
    // together in memory.
    let (old_index, new_index) = first_use_order(positions.len(), &triangles);
    let local_triangles: Vec<[u32; 3]> = triangles
        .par_iter()
        .map(|t| t.map(|x| new_index[x as usize]))
        .collect();
    drop(triangles);
    let local_positions: Vec<[f64; 3]> = old_index
        .par_iter()
        .map(|&x| positions[x as usize])
        .collect();
    let local_sizes: Vec<f64> = old_index.par_iter().map(|&x| sizes[x as usize]).collect();
    let local_pinned: Vec<bool> = old_index
        .par_iter()
        .map(|&x| pinned.get(x as usize).copied().unwrap_or(false))
        .collect();
    let local = simplify_chunked(
        &local_positions,
        &local_sizes,
        local_triangles,
        &local_pinned,
        &|v: u32| work(old_index[v as usize]),
    );
    // A vertex no triangle uses (none here: every vertex comes from a triangle) is kept as is.
    let keep: Vec<bool> = new_index
        .par_iter()
        .map(|&v| v == u32::MAX || local.keep[v as usize])
        .collect();
    let triangles = local
        .triangles
        .par_iter()
        .map(|t| t.map(|x| old_index[x as usize]))
        .collect();
    let kept: Vec<u32> = (0..keep.len() as u32)
        .filter(|&old| keep[old as usize])
        .collect();
    let results = kept
        .par_iter()
        .map(|&old| match new_index[old as usize] {
            u32::MAX => work(old),
            v => local.result(v),
        })
        .collect();
    Simplified {
        keep,
        triangles,
        results,
    }
}

/// The vertices of `triangles` in order of first use (`old_index`: new number → vertex), and
/// the inverse (`new_index`: vertex → new number, `u32::MAX` for a vertex no triangle uses).
/// In parallel: each vertex's first corner (3·triangle + slot) is the minimum over its
/// corners (an atomic minimum, whatever order the threads take), each block of
/// [`RENUMBER_BLOCK`] triangles lists the vertices whose first corner it holds, and the blocks'
/// lists are concatenated in order — the same numbering as one sequential scan.
fn first_use_order(n_vertices: usize, triangles: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let first: Vec<AtomicUsize> = (0..n_vertices)
        .into_par_iter()
        .map(|_| AtomicUsize::new(usize::MAX))
        .collect();
    triangles.par_iter().enumerate().for_each(|(t, tri)| {
        for (k, &x) in tri.iter().enumerate() {
            // Most corners are not the first (about 6 per vertex), and a plain load tells.
            let slot = &first[x as usize];
            if slot.load(Ordering::Relaxed) > 3 * t + k {
                slot.fetch_min(3 * t + k, Ordering::Relaxed);
            }
        }
    });
    let blocks: Vec<Vec<u32>> = triangles
        .par_chunks(RENUMBER_BLOCK)
        .enumerate()
        .map(|(b, block)| {
            let base = 3 * b * RENUMBER_BLOCK;
            let mut firsts = Vec::new();
            for (t, tri) in block.iter().enumerate() {
                for (k, &x) in tri.iter().enumerate() {
                    if first[x as usize].load(Ordering::Relaxed) == base + 3 * t + k {
                        firsts.push(x);
                    }
                }
            }
            firsts
        })
        .collect();
    let old_index = blocks.concat();
    old_index
        .par_iter()
        .enumerate()
        .for_each(|(i, &x)| first[x as usize].store(i, Ordering::Relaxed));
    let new_index = first
        .into_par_iter()
        .map(|slot| u32::try_from(slot.into_inner()).unwrap_or(u32::MAX))
        .collect();
    (old_index, new_index)
}

/// [`simplify`] on vertices numbered by first use, in two passes. First, in parallel, each chunk
/// of [`CHUNK`] consecutive vertices is simplified on its own triangles (those whose three
/// vertices are all in the chunk), with the vertices that also touch other triangles frozen:
/// a collapse only reads and writes the stars of u, v, w₁, w₂, which are then complete, and
/// the triangles of u, which are the chunk's own, so chunks never see each other's changes.
/// Then one sequential pass tries the vertices that were frozen ([`second_pass`]: on the part of
/// the mesh around them, with the result of a pass over the whole mesh). The chunks are fixed by
/// the numbering, so the result does not depend on the thread count.
fn simplify_chunked<T, W>(
    positions: &[[f64; 3]],
    sizes: &[f64],
    triangles: Vec<[u32; 3]>,
    pinned: &[bool],
    work: &W,
) -> Chunked<T>
where
    T: Copy + Send + Sync,
    W: Fn(u32) -> T + Sync,
{
    let n_vertices = positions.len();
    let n_chunks = n_vertices.div_ceil(CHUNK);
    let chunk_of = |v: u32| v as usize / CHUNK;
    // Each block of triangles split into the chunks' own triangles and the shared ones, in
    // parallel; then concatenated per chunk in block order (the input's order, as before).
    let blocks: Vec<_> = triangles
        .par_chunks(RENUMBER_BLOCK)
        .map(|block| {
            let mut own: Vec<Vec<[u32; 3]>> = vec![Vec::new(); n_chunks];
            let mut shared = Vec::new();
            for &t in block {
                let c = chunk_of(t[0]);
                if chunk_of(t[1]) == c && chunk_of(t[2]) == c {
                    own[c].push(t);
                } else {
                    shared.push(t);
                }
            }
            (own, shared)
        })
        .collect();
    drop(triangles);
    let own: Vec<Vec<[u32; 3]>> = (0..n_chunks)
        .into_par_iter()
        .map(|c| {
            let mut tris = Vec::with_capacity(blocks.iter().map(|b| b.0[c].len()).sum());
            for b in &blocks {
                tris.extend_from_slice(&b.0[c]);
            }
            tris
        })
        .collect();
    let mut shared = Vec::with_capacity(blocks.iter().map(|b| b.1.len()).sum());
    for b in &blocks {
        shared.extend_from_slice(&b.1);
    }
    drop(blocks);
    let mut border = vec![false; n_vertices];
    for t in &shared {
        for &x in t {
            border[x as usize] = true;
        }
    }
    // A pinned vertex is frozen everywhere: never removed, never moved onto, its star never
    // changed.
    let untouchable: Vec<bool> = border.iter().zip(pinned).map(|(&b, &p)| b || p).collect();
    let everyone = vec![true; CHUNK];
    let parts: Vec<ChunkPart<T>> = own
        .into_par_iter()
        .enumerate()
        .map(|(c, tris)| {
            let start = c * CHUNK;
            let end = (start + CHUNK).min(n_vertices);
            let offset = start as u32;
            let local: Vec<[u32; 3]> = tris.iter().map(|t| t.map(|x| x - offset)).collect();
            let part = simplify_local(
                &positions[start..end],
                &sizes[start..end],
                local,
                &untouchable[start..end],
                &everyone[..end - start],
                |v| v + offset,
            );
            // The chunk's kept vertices off its border are final: the sequential pass
            // removes border vertices only.
            let settled: Vec<u32> = (start..end)
                .filter(|&v| part.keep[v - start] && !border[v])
                .map(|v| v as u32)
                .collect();
            ChunkPart {
                triangles: part
                    .alive_triangles()
                    .map(|t| t.map(|x| x + offset))
                    .collect(),
                keep: part.keep,
                results: work_on(&settled, work),
            }
        })
        .collect();
    let mut keep = Vec::with_capacity(n_vertices);
    let mut lists = Vec::with_capacity(n_chunks + 1);
    let mut merged = shared;
    merged.reserve(parts.iter().map(|p| p.triangles.len()).sum());
    for part in parts {
        keep.extend(part.keep);
        merged.extend(part.triangles);
        lists.push(part.results);
    }
    // The border vertices are all kept so far (frozen in the chunks): their work runs ahead,
    // beside the sequential pass.
    let border_vertices: Vec<u32> = (0..n_vertices as u32)
        .filter(|&v| border[v as usize])
        .collect();
    let (triangles, border_results) = rayon::join(
        || {
            let second = second_pass(positions, sizes, &merged, &border, pinned);
            for (&v, &k) in second.vertices.iter().zip(&second.swept.keep) {
                keep[v as usize] &= k;
            }
            // The triangles the second pass did not see are unchanged.
            let mut changed = second
                .triangles
                .iter()
                .zip(second.swept.triangles.iter().zip(&second.swept.alive))
                .peekable();
            let mut triangles = Vec::with_capacity(merged.len());
            for (i, t) in merged.iter().enumerate() {
                match changed.peek() {
                    Some(&(&j, (local, &alive))) if j as usize == i => {
                        if alive {
                            triangles.push(local.map(|x| second.vertices[x as usize]));
                        }
                        changed.next();
                    }
                    _ => triangles.push(*t),
                }
            }
            triangles
        },
        || work_on(&border_vertices, work),
    );
    // Where each surviving vertex's result is: its chunk's list (in vertex order) or the border
    // list.
    let mut slot = vec![(u32::MAX, 0); n_vertices];
    slot.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, slots)| {
            let mut next = 0;
            for (i, s) in slots.iter_mut().enumerate() {
                let v = c * CHUNK + i;
                if keep[v] && !border[v] {
                    *s = (c as u32, next);
                    next += 1;
                }
            }
        });
    for (i, &v) in border_vertices.iter().enumerate() {
        slot[v as usize] = (n_chunks as u32, i as u32);
    }
    lists.push(border_results);
    Chunked {
        keep,
        triangles,
        slot,
        lists,
    }
}

/// The second pass of [`simplify_chunked`] on the part of the mesh it can touch, in local
/// numbers: `vertices` (increasing) and `triangles` (increasing) name that part in the whole
/// mesh.
struct SecondPass {
    vertices: Vec<u32>,
    triangles: Vec<u32>,
    swept: Swept,
}

/// The sequential pass over the `border` vertices (the only candidates) on the part of the
/// mesh `triangles` it can touch: the zone of the border vertices and their neighbours, and
/// every triangle with a vertex in the zone. Working there gives exactly the result of the pass
/// over the whole mesh. A collapse u → v of a border vertex u reads the positions of u's
/// neighbours, the stars of u, v, w₁, w₂ (all neighbours of u) and the triangles around v, and
/// rewrites u's triangles; so, by induction over the collapses, every neighbour of a border
/// vertex stays in the zone (the vertex a border vertex moves onto was its neighbour), the
/// stars of the zone stay complete (only triangles around border vertices change), and the
/// vertices outside the zone, which are frozen here because their stars are incomplete, are
/// never touched. The visiting order is the same because it is set by the whole-mesh numbers.
fn second_pass(
    positions: &[[f64; 3]],
    sizes: &[f64],
    triangles: &[[u32; 3]],
    border: &[bool],
    pinned: &[bool],
) -> SecondPass {
    let n_vertices = positions.len();
    let mut zone = vec![false; n_vertices];
    for t in triangles {
        if t.iter().any(|&x| border[x as usize]) {
            for &x in t {
                zone[x as usize] = true;
            }
        }
    }
    let picked: Vec<u32> = (0..triangles.len() as u32)
        .filter(|&i| triangles[i as usize].iter().any(|&x| zone[x as usize]))
        .collect();
    let mut local_id = vec![u32::MAX; n_vertices];
    for &i in &picked {
        for &x in &triangles[i as usize] {
            local_id[x as usize] = 0;
        }
    }
    let mut vertices = Vec::new();
    for (x, id) in local_id.iter_mut().enumerate() {
        if *id != u32::MAX {
            *id = vertices.len() as u32;
            vertices.push(x as u32);
        }
    }
    let local_triangles = picked
        .iter()
        .map(|&i| triangles[i as usize].map(|x| local_id[x as usize]))
        .collect();
    let local_positions: Vec<[f64; 3]> = vertices.iter().map(|&x| positions[x as usize]).collect();
    let local_sizes: Vec<f64> = vertices.iter().map(|&x| sizes[x as usize]).collect();
    let frozen: Vec<bool> = vertices
        .iter()
        .map(|&x| !zone[x as usize] || pinned[x as usize])
        .collect();
    let candidate: Vec<bool> = vertices
        .iter()
        .map(|&x| border[x as usize] && !pinned[x as usize])
        .collect();
    let swept = simplify_local(
        &local_positions,
        &local_sizes,
        local_triangles,
        &frozen,
        &candidate,
        |v| vertices[v as usize],
    );
    SecondPass {
        vertices,
        triangles: picked,
        swept,
    }
}

/// The result of one sweep: `keep[v]` per vertex, and every input triangle (in the input's
/// order, its vertices replaced by the collapses) with whether it is still alive.
struct Swept {
    keep: Vec<bool>,
    triangles: Vec<[u32; 3]>,
    alive: Vec<bool>,
}

impl Swept {
    /// The surviving triangles, in order.
    fn alive_triangles(&self) -> impl Iterator<Item = [u32; 3]> + '_ {
        self.triangles
            .iter()
            .zip(&self.alive)
            .filter(|&(_, &a)| a)
            .map(|(t, _)| *t)
    }
}

/// Core of [`simplify`]: one sequential sweep.
/// `frozen[v]`: v may not be touched (its star is incomplete here); `candidate[v]`: v may be
/// removed; `rank[v]`: v's number in the whole mesh (increasing with v), which sets the
/// visiting order.
fn simplify_local(
    positions: &[[f64; 3]],
    sizes: &[f64],
    triangles: Vec<[u32; 3]>,
    frozen: &[bool],
    candidate: &[bool],
    rank: impl Fn(u32) -> u32,
) -> Swept {
    let n_vertices = positions.len();
    let mut valence = vec![0u32; n_vertices];
    for tri in &triangles {
        for &x in tri {
            valence[x as usize] += 1;
        }
    }
    let mut around: Vec<Star> = valence
        .iter()
        .zip(frozen)
        .map(|(&n, &frozen)| Star {
            len: if frozen || n as usize > STAR_CAPACITY {
                Star::FROZEN
            } else {
                0
            },
            triangles: [0; STAR_CAPACITY],
        })
        .collect();
    for (t, tri) in triangles.iter().enumerate() {
        for &x in tri {
            if !around[x as usize].is_frozen() {
                around[x as usize].push(t as u32);
            }
        }
    }
    // Candidates: the shortest edge relative to the local size, below SHORT_EDGE.
    let mut shortest = vec![f64::INFINITY; n_vertices];
    for tri in &triangles {
        for k in 0..3 {
            let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
            // Only the candidates' shortest edges are used.
            if !candidate[a] && !candidate[b] {
                continue;
            }
            let d = distance(positions[a], positions[b]);
            shortest[a] = shortest[a].min(d / sizes[a]);
            shortest[b] = shortest[b].min(d / sizes[b]);
        }
    }
    let mut order: Vec<(u64, u32)> = shortest
        .iter()
        .enumerate()
        .filter(|&(v, &s)| s < SHORT_EDGE && candidate[v])
        .map(|(v, &s)| (s.to_bits(), v as u32))
        .collect();
    // Sorted within blocks of consecutive vertices (close in space), so the sweep stays in
    // cache.
    order.sort_unstable_by_key(|&(s, v)| {
        let r = rank(v);
        (r / ORDER_BLOCK, s, r)
    });
    let mut mesh = Mesh {
        alive: vec![true; triangles.len()],
        triangles,
        around,
    };
    let mut keep = vec![true; n_vertices];
    let mut cycle = Vec::new();
    let mut link_edges = Vec::new();
    let mut candidates: Vec<(f64, usize)> = Vec::new();
    let mut ring: Vec<RingVertex> = Vec::new();
    let mut mark = vec![u32::MAX; n_vertices];
    for (stamp, (_, u)) in order.into_iter().enumerate() {
        if !mesh.link_cycle(u, &mut cycle, &mut link_edges) {
            continue;
        }
        let stamp = stamp as u32;
        for &x in &cycle {
            mark[x as usize] = stamp;
        }
        let mut old_worst = f64::INFINITY;
        for &t in mesh.around[u as usize].as_slice() {
            let [a, b, c] = mesh.triangles[t as usize].map(|x| positions[x as usize]);
            old_worst = old_worst.min(shape(a, b, c).0);
        }
        let floor = old_worst.min(GOOD_QUALITY);
        // Targets nearest first; the first that keeps every triangle well shaped wins, else the
        // best one that does not make the worst triangle around u worse.
        let pu = positions[u as usize];
        candidates.clear();
        ring.clear();
        for (i, &v) in cycle.iter().enumerate() {
            let position = positions[v as usize];
            let d = sub(position, pu);
            candidates.push((dot(d, d), i));
            ring.push(RingVertex {
                vertex: v,
                position,
                normal: [0.0; 3],
                normal2: 0.0,
            });
        }
        let n = ring.len();
        for k in 0..n {
            let (pa, pb) = (ring[k].position, ring[(k + 1) % n].position);
            let normal = cross(sub(pa, pu), sub(pb, pu));
            ring[k].normal = normal;
            ring[k].normal2 = dot(normal, normal);
        }
        candidates.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let size_u = sizes[u as usize];
        let mut best: Option<(f64, u32)> = None;
        for &(_, i) in &candidates {
            let limit = MAX_EDGE * size_u.min(sizes[cycle[i] as usize]);
            if let Some(q) = mesh.collapse_quality(&ring, i, limit * limit, (&mark, stamp))
                && q >= floor
                && best.is_none_or(|(b, _)| q > b)
            {
                best = Some((q, cycle[i]));
                if q >= GOOD_QUALITY {
                    break;
                }
            }
        }
        if let Some((_, v)) = best {
            mesh.collapse(u, v);
            keep[u as usize] = false;
        }
    }
    Swept {
        keep,
        triangles: mesh.triangles,
        alive: mesh.alive,
    }
}
