//! `stablesurf render`: a shaded PNG picture of a mesh file.

use anyhow::{anyhow, Result};
use stablesurf::export;
use stablesurf::render::{self as render_stage, RenderParams};

use super::args::RenderArgs;
use super::config;

/// Runs `stablesurf render`.
pub fn render(args: RenderArgs) -> Result<()> {
    // `--size` is within range::SIZE.
    let cloud = config::read_cloud(&args.mesh)?;
    if cloud.triangles.is_empty() {
        return Err(anyhow!(
            "{} has no faces to render (it is a point cloud)",
            args.mesh.display()
        ));
    }
    let mesh = render_stage::with_face_normals(cloud.points, cloud.triangles);
    let params = RenderParams {
        size: args.size,
        view: args.view.into(),
        up: args.up.into(),
        ..Default::default()
    };
    let image = render_stage::render(&mesh, &params);
    export::write_atomic(&args.output, |w| export::png::write_rgb(&image, w))?;
    Ok(())
}
