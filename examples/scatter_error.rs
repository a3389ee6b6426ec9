//! Error of the scattered irradiance against run time: Ingersoll's bowl crater.
//!
//! ```text
//! cargo run --release --example scatter_error
//! ```
//! For meshes of 600 to ~10,000 facets, both solvers and three tolerances: the mean and
//! largest relative error of the scattered irradiance over the shadowed facets against
//! Ingersoll's closed form (`slim::scatter::bowl`), the iterations, and the time of the
//! form factors (once per body) and of one step's solve. Prints a Markdown table.

use slim::scatter::bowl::BowlCase;
use slim::scatter::solve::SolverKind;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("| facets | solver | tolerance | mean error | max error | iterations | form factors s | solve ms |");
    println!("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |");
    for rings in [10, 20, 30, 41] {
        for solver in [SolverKind::Jacobi, SolverKind::Cg] {
            for tolerance in [1e-2, 1e-4, 1e-6] {
                let r = BowlCase {
                    rings,
                    solver,
                    tolerance,
                }
                .run()?;
                println!(
                    "| {} | {} | {tolerance:.0e} | {:.3} % | {:.2} % | {} | {:.2} | {:.2} |",
                    r.facets,
                    r.report.method,
                    100.0 * r.mean_error,
                    100.0 * r.max_error,
                    r.report.iterations,
                    r.form_factor_s,
                    1e3 * r.solve_s
                );
            }
        }
    }
    Ok(())
}
