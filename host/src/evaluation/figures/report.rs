//! A figure's Markdown summary: per case and method the best N, R there,
//! at N = 20 and with all pixels (kept negative pixels, and clipped at 0),
//! the N range within 5% of the best and the range the data cannot tell
//! from the best; then every rule against subtract-next, paired; for
//! figures run with several seeds, the same pooled over the seeds.

use std::fmt::Write as _;

use super::{axis_words, best_row, FigureResult, Row, CLIPPED_ALL};
use crate::evaluation::stats::{indistinguishable_from_best, pooled, zero_crossings};
use crate::evaluation::{Axis, Estimate, Method, Score};

fn pm(e: Estimate) -> String {
    format!("{:.4} ± {:.4}", e.value, e.se)
}

fn signed(e: Estimate) -> String {
    format!("{:+.4} ± {:.4} ({:+.1} se)", e.value, e.se, e.value / e.se)
}

/// The scores of `method` in case `ci`, sorted by N.
fn curve(result: &FigureResult, ci: usize, m: Method) -> Vec<&Score> {
    let mut v: Vec<&Score> = result
        .rows
        .iter()
        .filter(|r| r.case == ci && r.score.method == m)
        .map(|r| &r.score)
        .collect();
    v.sort_by_key(|s| s.pixels);
    v
}

fn best_of<'a>(scores: &[&'a Score], axis: Axis) -> Option<&'a Score> {
    scores
        .iter()
        .copied()
        .min_by(|a, b| a.mse(axis).value.total_cmp(&b.mse(axis).value))
}

fn range(ns: &[usize]) -> String {
    match (ns.first(), ns.last()) {
        (Some(a), Some(b)) => format!("{a}..{b}"),
        _ => "-".into(),
    }
}

/// Markdown summary of a figure.
pub fn summary(result: &FigureResult) -> String {
    let fig = &result.figure;
    let axis = fig.axis;
    let frames = result.rows.first().map_or(0, |r| r.frames);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "### {} (`{}`)\n\n{} frames per case, R {} in pixels, ± one standard error; {:.0} s. \
         \"Not resolved\": the N whose R exceeds the best by less than 2 standard errors of the paired difference.\n",
        fig.title,
        fig.name,
        frames,
        axis_words(axis),
        result.seconds
    );
    let _ = writeln!(
        s,
        "| case | method | best N | R(best) | R(N=20) | R(all) | R(all, clipped at 0) | within 5% | not resolved | R(all) - R(best), paired | R(slope 0) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for (ci, c) in fig.cases.iter().enumerate() {
        let clipped = result
            .rows
            .iter()
            .find(|r| r.case == ci && r.score.method == CLIPPED_ALL)
            .map_or("-".into(), |r| pm(r.score.r(axis)));
        for &m in &fig.methods {
            let scores = curve(result, ci, m);
            let Some(best) = best_of(&scores, axis) else {
                continue;
            };
            let rb = best.r(axis);
            let at = |n: usize| scores.iter().find(|r| r.pixels == n && !r.all_pixels);
            let all = scores.iter().find(|r| r.all_pixels);
            let near: Vec<usize> = scores
                .iter()
                .filter(|r| r.r(axis).value <= 1.05 * rb.value)
                .map(|r| r.pixels)
                .collect();
            let flat = indistinguishable_from_best(&scores, axis, 2.0);
            let fmt = |r: Option<&&Score>| r.map_or("-".into(), |r| pm(r.r(axis)));
            let gain = all.map_or("-".into(), |a| pm(a.paired_difference(best, axis)));
            let _ = writeln!(
                s,
                "| {} | {} | {}{} | {} | {} | {} | {} | {} | {} | {} | {:.3} |",
                c.label,
                m.label(),
                best.pixels,
                if best.all_pixels { " (all)" } else { "" },
                pm(rb),
                fmt(at(20)),
                fmt(all),
                clipped,
                range(&near),
                range(&flat),
                gain,
                result.zero_r.get(ci).copied().unwrap_or(f64::NAN)
            );
        }
    }
    let others: Vec<Method> = fig
        .methods
        .iter()
        .copied()
        .filter(|&m| m != Method::SUBTRACT_NEXT)
        .collect();
    if fig.methods.contains(&Method::SUBTRACT_NEXT) && !others.is_empty() {
        let _ = writeln!(
            s,
            "\nRules against subtract-next, paired on the same frames (negative: the rule is better than subtract-next):\n"
        );
        let _ = writeln!(
            s,
            "| case | rule | R(rule) - R(subtract-next), each at its best N | at N = 20 |"
        );
        let _ = writeln!(s, "|---|---|---|---|");
        for (ci, c) in fig.cases.iter().enumerate() {
            let sn = curve(result, ci, Method::SUBTRACT_NEXT);
            let (Some(sn_best), Some(sn20)) = (
                best_of(&sn, axis),
                sn.iter().find(|r| r.pixels == 20 && !r.all_pixels),
            ) else {
                continue;
            };
            for &m in &others {
                let o = curve(result, ci, m);
                let (Some(o_best), Some(o20)) = (
                    best_of(&o, axis),
                    o.iter().find(|r| r.pixels == 20 && !r.all_pixels),
                ) else {
                    continue;
                };
                let _ = writeln!(
                    s,
                    "| {} | {} (N={} vs {}) | {} | {} |",
                    c.label,
                    m.label(),
                    o_best.pixels,
                    sn_best.pixels,
                    signed(o_best.paired_difference(sn_best, axis)),
                    signed(o20.paired_difference(sn20, axis))
                );
            }
        }
    }
    if fig.cases.iter().any(|c| c.seed_offset > 0) {
        s.push_str(&seeds_section(result));
    }
    if fig.methods.contains(&Method::THRESHOLD) && fig.methods.contains(&Method::SUBTRACT_NEXT) {
        s.push_str(&crossover_section(result));
    }
    let invalid: usize = result.rows.iter().map(|r| r.score.invalid).sum();
    let saturated: usize = result
        .rows
        .iter()
        .filter(|r| r.score.all_pixels)
        .map(|r| r.saturated)
        .sum();
    let light = result
        .rows
        .iter()
        .map(|r| r.field_fraction)
        .fold(1.0, f64::min);
    let _ = writeln!(
        s,
        "\nInvalid engine results (flux <= 0): {invalid}; saturated pixels: {saturated}; least light inside the window: {:.2}%.",
        100.0 * light
    );
    s
}

/// Figures whose cases are one condition under several seeds: the best N
/// of each seed, and R and the paired differences pooled over all frames.
fn seeds_section(result: &FigureResult) -> String {
    let fig = &result.figure;
    let axis = fig.axis;
    let mut s = String::new();
    let cases: Vec<usize> = (0..fig.cases.len()).collect();
    let _ = writeln!(
        s,
        "\nPooled over the {} seeds ({} frames per rule and N):\n",
        cases.len(),
        cases.len() * result.rows.first().map_or(0, |r| r.frames)
    );
    let _ = writeln!(
        s,
        "| method | best N per seed | pooled best N | pooled R(best) | pooled R(N=20) | not resolved (pooled) | R - R(subtract-next), each at its pooled best N |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    let pooled_curve = |m: Method| -> Vec<Score> {
        let first = curve(result, 0, m);
        first
            .iter()
            .map(|s0| {
                let parts: Vec<&Score> = cases
                    .iter()
                    .filter_map(|&ci| {
                        result
                            .rows
                            .iter()
                            .map(|r: &Row| r)
                            .find(|r| {
                                r.case == ci && r.score.method == m && r.score.pixels == s0.pixels
                            })
                            .map(|r| &r.score)
                    })
                    .collect();
                pooled(&parts)
            })
            .collect()
    };
    let sn = pooled_curve(Method::SUBTRACT_NEXT);
    let sn_refs: Vec<&Score> = sn.iter().collect();
    let sn_best = best_of(&sn_refs, axis);
    for &m in &fig.methods {
        let per_seed: Vec<String> = cases
            .iter()
            .filter_map(|&ci| best_row(result, ci, m, axis).map(|r| r.score.pixels.to_string()))
            .collect();
        let curve = pooled_curve(m);
        let refs: Vec<&Score> = curve.iter().collect();
        let Some(best) = best_of(&refs, axis) else {
            continue;
        };
        let at20 = refs.iter().find(|r| r.pixels == 20 && !r.all_pixels);
        let diff = match sn_best {
            Some(b) if m != Method::SUBTRACT_NEXT => signed(best.paired_difference(b, axis)),
            _ => "-".into(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} |",
            m.label(),
            per_seed.join(", "),
            best.pixels,
            pm(best.r(axis)),
            at20.map_or("-".into(), |r| pm(r.r(axis))),
            range(&indistinguishable_from_best(&refs, axis, 2.0)),
            diff
        );
    }
    s
}

/// Where, along the figure's parameter, threshold overtakes subtract-next:
/// at fixed N (10, 20, 32, 50) and each at its best N, from the paired
/// differences of each case, interpolated between the bracketing cases
/// ([`zero_crossing`]).
fn crossover_section(result: &FigureResult) -> String {
    let fig = &result.figure;
    let axis = fig.axis;
    if fig.cases.len() < 3 {
        return String::new();
    }
    let diff_at = |ci: usize, n: Option<usize>| -> Option<Estimate> {
        let pick = |m: Method| -> Option<&Score> {
            let c = curve(result, ci, m);
            match n {
                Some(n) => c.into_iter().find(|r| r.pixels == n && !r.all_pixels),
                None => best_of(&c, axis),
            }
        };
        Some(pick(Method::THRESHOLD)?.paired_difference(pick(Method::SUBTRACT_NEXT)?, axis))
    };
    let mut s = format!(
        "\nWhere threshold overtakes subtract-next along `{}` (every sign change of R(threshold) - R(subtract-next), paired; linear interpolation between the bracketing cases, standard error by the delta method):\n\n| N | crossover |\n|---|---|\n",
        fig.parameter
    );
    for n in [Some(10), Some(20), Some(32), Some(50), None] {
        let points: Vec<(f64, Estimate)> = (0..fig.cases.len())
            .filter_map(|ci| diff_at(ci, n).map(|d| (fig.cases[ci].value, d)))
            // se = 0: the same estimator on both sides (all pixels).
            .filter(|(_, d)| d.value.is_finite() && d.se.is_finite() && d.se > 0.0)
            .collect();
        let label = n.map_or("each at its best N".to_string(), |n| n.to_string());
        let crossings = zero_crossings(&points);
        let text = if crossings.is_empty() {
            "none in the range computed".to_string()
        } else {
            crossings
                .iter()
                .map(|c| format!("{:.2} ± {:.2}", c.value, c.se))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = writeln!(s, "| {label} | {text} |");
    }
    s
}
