//! Topo3D's bowl crater refined: scattered light against Ingersoll's closed form.
//!
//! ```text
//! cargo run --release --example crater_refinement [CELLS...]
//! ```
//! For each pixel count across Topo3D's 400 m square (default 40, 60, 80, 100 and 120, i.e.
//! 10 m to 3.3 m pixels; 80 is Topo3D's own `topo81.xyz`), the crater is sampled from its
//! sphere (`slim::scatter::bowl::topo3d_height`) and lit as in Topo3D's run 1. Prints a
//! Markdown table: the mean error of the scattered irradiance over shadowed and sunlit
//! facets, away from the rim cells and with them, the view factor to the bowl against
//! the sphere's, and the form factors' time. Memory grows as the square of the crater's
//! facets (about 1 GB at 120 cells).

use slim::scatter::bowl::{topo3d_dem, topo3d_height, topo3d_run};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut cells: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    if cells.is_empty() {
        cells = vec![40, 60, 80, 100, 120];
    }
    println!("| pixel m | facets | shadowed, interior | sunlit, interior | shadowed, all | sunlit, all | view factor, interior | view factor, rim cells | rim share of sunlit | form factors s |");
    println!("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    let pct = |e: f64| format!("{:+.2} %", 100.0 * e);
    for c in cells {
        let r = topo3d_run(topo3d_dem(c, topo3d_height))?;
        println!(
            "| {:.2} | {} | {} | {} | {} | {} | {} | {} | {:.0} % | {:.1} |",
            400.0 / c as f64,
            r.facets,
            pct(r.shadowed_interior),
            pct(r.sunlit_interior),
            pct(r.shadowed_all),
            pct(r.sunlit_all),
            pct(r.view_interior),
            pct(r.view_rim),
            100.0 * r.rim_share_of_sunlit,
            r.form_factor_s
        );
    }
    Ok(())
}
