//! Benchmarks of the `import` stage.
//!
//! - `ascii_bunny`: reading ../shared/data/bunny_zipper.ply (3 MB ascii PLY, 35,947 vertices,
//!   69,451 faces) with `read_scan`, and with ply-rs-bw's reader as the baseline.
//! - `binary_ply_1m`: a generated binary little-endian PLY with 1,000,000 vertices (float x y z
//!   nx ny nz) and 1,996,002 triangles (about 50 MB) in a temp dir: `read_scan` from the file
//!   (page cache), `read_scan_bytes` from memory, and ply-rs-bw's reader on the same bytes.
//!   Throughput is in bytes, so criterion prints MB/s.
//! - `obj`: ../shared/data/max_planck.obj with this crate's reader and with tobj.
//!
//! Run: `cargo bench --bench import`. The shared-data groups are skipped with a notice when
//! ../shared/data is absent.

use std::hint::black_box;
use std::io::Write as _;
use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{BeginList, PropertyAccess, PropertyAccessResult};
use stablesurf::import::{read_scan, read_scan_bytes};
use stablesurf::PointCloud;

// The generator of the 1M-point file, shared with the `gen_big_ply` example.
#[allow(dead_code)]
#[path = "../tools/gen_big_ply.rs"]
mod gen_big_ply;
use gen_big_ply::big_ply;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");

/// ply-rs-bw's element types: a vertex keeping x/y/z (float or double), a face keeping its index
/// list, and an element that ignores everything.
#[derive(Default)]
struct Vertex([f64; 3]);

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Vertex::default()
    }
    fn set_float(&mut self, name: &str, value: f32) -> PropertyAccessResult {
        self.set_double(name, f64::from(value))
    }
    fn set_double(&mut self, name: &str, value: f64) -> PropertyAccessResult {
        match name {
            "x" => self.0[0] = value,
            "y" => self.0[1] = value,
            "z" => self.0[2] = value,
            _ => return PropertyAccessResult::Ignored,
        }
        PropertyAccessResult::Set
    }
}

#[derive(Default)]
struct Face(Vec<i32>);

impl PropertyAccess for Face {
    fn new() -> Self {
        Face::default()
    }
    fn begin_list_int(&mut self, name: &str, _len: usize) -> BeginList<'_, i32> {
        match name {
            "vertex_indices" => BeginList::Fill(&mut self.0),
            _ => BeginList::UseSetter,
        }
    }
}

struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// The same cloud through ply-rs-bw's reader (float/double coordinates, int face lists).
fn read_with_ply_rs_bw(bytes: &[u8]) -> PointCloud {
    let mut reader = Reader::new(bytes);
    let header = Parser::<Skip>::new().read_header(&mut reader).unwrap();
    let mut cloud = PointCloud::default();
    for element in header.elements.values() {
        match element.name.as_str() {
            "vertex" => {
                let v = Parser::<Vertex>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .unwrap();
                cloud.points = v.into_iter().map(|v| v.0).collect();
            }
            "face" => {
                let faces = Parser::<Face>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .unwrap();
                for f in faces {
                    for k in 1..f.0.len().saturating_sub(1) {
                        cloud
                            .triangles
                            .push([f.0[0] as u32, f.0[k] as u32, f.0[k + 1] as u32]);
                    }
                }
            }
            _ => {
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .unwrap();
            }
        }
    }
    cloud
}

fn ascii_bunny(c: &mut Criterion) {
    let path = Path::new(DATA).join("bunny_zipper.ply");
    let Ok(bytes) = std::fs::read(&path) else {
        eprintln!("notice: {} is absent; skipping ascii_bunny", path.display());
        return;
    };
    let mut group = c.benchmark_group("ascii_bunny");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.sample_size(20);
    group.bench_function("read_scan", |b| {
        b.iter(|| read_scan(black_box(&path)).unwrap())
    });
    group.bench_function("ply_rs_bw", |b| {
        b.iter(|| read_with_ply_rs_bw(black_box(&bytes)))
    });
    group.finish();
}

fn binary_ply_1m(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.ply");
    let bytes = big_ply(1000);
    std::fs::File::create(&path)
        .unwrap()
        .write_all(&bytes)
        .unwrap();
    // The two readers agree before they are timed.
    let ours = read_scan_bytes(&bytes, &path).unwrap().cloud;
    let theirs = read_with_ply_rs_bw(&bytes);
    assert_eq!(ours.points, theirs.points);
    assert_eq!(ours.triangles, theirs.triangles);
    let mut group = c.benchmark_group("binary_ply_1m");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(8));
    group.bench_function("read_scan_file", |b| {
        b.iter(|| read_scan(black_box(&path)).unwrap())
    });
    group.bench_function("read_scan_bytes", |b| {
        b.iter(|| read_scan_bytes(black_box(&bytes), &path).unwrap())
    });
    group.bench_function("ply_rs_bw", |b| {
        b.iter(|| read_with_ply_rs_bw(black_box(&bytes)))
    });
    group.finish();
}

fn obj(c: &mut Criterion) {
    let path = Path::new(DATA).join("max_planck.obj");
    let Ok(bytes) = std::fs::read(&path) else {
        eprintln!("notice: {} is absent; skipping obj", path.display());
        return;
    };
    let mut group = c.benchmark_group("obj");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.bench_function("read_scan_bytes", |b| {
        b.iter(|| read_scan_bytes(black_box(&bytes), &path).unwrap())
    });
    let options = tobj::LoadOptions {
        triangulate: true,
        ..Default::default()
    };
    group.bench_function("tobj", |b| {
        b.iter(|| {
            tobj::load_obj_buf(&mut black_box(&bytes[..]), &options, |_| {
                Err(tobj::LoadError::OpenFileFailed)
            })
            .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, ascii_bunny, binary_ply_1m, obj);
criterion_main!(benches);
