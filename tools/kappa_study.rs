//! The κ study: six synthetic shapes × degrees 4, 6, 8 × clean / noisy (variance 0.0025,
//! normalized units) / 15% cut away × ε 0.05, 0.01, fitted with automatic κ under both rules,
//! each fit judged independently (`stablesurf::testing::study::assess`: positive leading form, one
//! zero-set component near the data, nothing else in [−4, 4]³). Prints one line per case and a
//! summary table (Markdown) for the README.
//!
//! Run: `cargo run --release --features tools --example kappa_study [-- POINTS [SEED]]` (default 3000 points per
//! case, seed 2008).

use stablesurf::fit::{fit, FitParams, KappaRule};
use stablesurf::testing::study::{assess, sample, Shape, Variant};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n_points: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(3000);
    let seed: u64 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(2008);
    let rules = [KappaRule::Stable, KappaRule::Paper];
    // good[rule][degree index], total[degree index]
    let mut good = [[0usize; 3]; 2];
    let mut total = [0usize; 3];
    let mut kappas: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); 3]; 2];
    let mut failures = Vec::new();
    println!("| shape | variant | degree | ε | stable κ | stable | paper κ | paper |");
    println!("|---|---|---|---|---|---|---|---|");
    for shape in Shape::ALL {
        for variant in Variant::ALL {
            let cloud = sample(shape, variant, n_points, seed);
            for (di, degree) in [4u32, 6, 8].into_iter().enumerate() {
                for epsilon in [0.05, 0.01] {
                    total[di] += 1;
                    let mut cells = Vec::new();
                    for (ri, rule) in rules.into_iter().enumerate() {
                        let params = FitParams {
                            degree,
                            epsilon,
                            kappa_rule: rule,
                            ..FitParams::default()
                        };
                        match fit(&cloud, &params) {
                            Ok(model) => {
                                let verdict = assess(&model.polynomial, &cloud);
                                let kappa = model.fit.as_ref().map_or(f64::NAN, |f| f.kappa);
                                kappas[ri][di].push(kappa);
                                if verdict.good {
                                    good[ri][di] += 1;
                                } else {
                                    failures.push(format!(
                                        "{} {} n={degree} eps={epsilon} rule={}: kappa {kappa:.1e} {verdict:?}",
                                        shape.name(),
                                        variant.name(),
                                        rule.as_str()
                                    ));
                                }
                                cells.push(format!("{kappa:.1e}"));
                                cells.push(if verdict.good {
                                    "good".into()
                                } else {
                                    format!("bad ({} comp.)", verdict.components)
                                });
                            }
                            Err(e) => {
                                cells.push("-".into());
                                cells.push(format!("error: {e}"));
                                failures.push(format!(
                                    "{} {} n={degree} eps={epsilon} rule={}: {e}",
                                    shape.name(),
                                    variant.name(),
                                    rule.as_str()
                                ));
                            }
                        }
                    }
                    println!(
                        "| {} | {} | {degree} | {epsilon} | {} |",
                        shape.name(),
                        variant.name(),
                        cells.join(" | ")
                    );
                }
            }
        }
    }
    println!();
    println!("| rule | degree 4 | degree 6 | degree 8 | all | median κ (4 / 6 / 8) |");
    println!("|---|---|---|---|---|---|");
    for (ri, rule) in rules.into_iter().enumerate() {
        let all: usize = good[ri].iter().sum();
        let n_all: usize = total.iter().sum();
        let medians: Vec<String> = kappas[ri]
            .iter()
            .map(|k| {
                let mut k = k.clone();
                k.sort_by(f64::total_cmp);
                k.get(k.len() / 2)
                    .map_or("-".into(), |m| format!("{m:.1e}"))
            })
            .collect();
        println!(
            "| {} | {}/{} | {}/{} | {}/{} | {}/{} ({:.0}%) | {} |",
            rule.as_str(),
            good[ri][0],
            total[0],
            good[ri][1],
            total[1],
            good[ri][2],
            total[2],
            all,
            n_all,
            100.0 * all as f64 / n_all as f64,
            medians.join(" / ")
        );
    }
    if !failures.is_empty() {
        eprintln!("\nnot good:");
        for f in failures {
            eprintln!("  {f}");
        }
    }
}
