//! `brightpix bench --port PORT`: the board's own bench mode (PROTOCOL.md
//! §14). The board measures the engine and the honest floor on its own
//! generated workloads (the QEMU bench's, `firmware/bench/`) and reports
//! counts per frame and after the frame's last row: DWT cycles on the
//! STM32H743, instructions on the QEMU board under `-icount` (uncounted
//! without it).

use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::{
    BenchFigures, BenchResult, CountUnit, FloorCheck, Spread, ALL_WORKLOADS,
};
use serde_json::json;

use crate::link::{BenchRow, Client};

/// What `bench --port` was asked.
pub struct PortBench<'a> {
    pub port: &'a str,
    pub workload: Option<&'a str>,
    /// 0: each workload's own count.
    pub frames: u32,
    pub json: Option<&'a Path>,
    /// Longest silence while one workload is measured.
    pub per_workload: Duration,
}

/// Runs the board's bench, prints the table (and writes the JSON).
pub fn run(request: &PortBench<'_>) -> Result<Vec<BenchRow>> {
    let mut client = Client::open(request.port)?;
    let board = client.info().board.clone();
    let workload = request.workload.unwrap_or(ALL_WORKLOADS);
    eprintln!(
        "brightpix bench: {board} on {} measures {workload} ({} frames each)...",
        request.port,
        if request.frames == 0 {
            "the workload's own count of".to_string()
        } else {
            request.frames.to_string()
        }
    );
    let rows = client
        .bench(workload, request.frames, request.per_workload, |row| {
            eprintln!("  {}: {}", row.workload, short(row));
        })
        .with_context(|| format!("the bench on {}", request.port))?;
    // The device's configuration and digest are untouched by a bench.
    let status = client.status()?;
    print!("{}", table(&board, &rows));
    if let Some(path) = request.json {
        let value = json!({
            "board": board,
            "port": request.port,
            "config_digest": status.config_digest,
            "workloads": rows.iter().map(row_json).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&value)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("brightpix bench: wrote {}", path.display());
    }
    if let Some(bad) = rows
        .iter()
        .find(|r| matches!(r.result, BenchResult::SlopesDiffer { .. }))
    {
        bail!(
            "{}: the engine's slopes differed from the floor's on the board (a fault: please report it)",
            bad.workload
        );
    }
    Ok(rows)
}

/// Count per pixel: over all measured frames.
pub fn per_pixel(row: &BenchRow, total: u64) -> f64 {
    total as f64 / (row.pixels as f64 * row.frames.max(1) as f64)
}

/// Million pixels per second at the board's clock (cycles only).
pub fn mpx_per_s(row: &BenchRow, f: &BenchFigures) -> Option<f64> {
    match (row.unit, row.clock_hz) {
        (CountUnit::Cycles, Some(hz)) if f.engine_total > 0 => {
            Some(hz as f64 / per_pixel(row, f.engine_total) / 1e6)
        }
        _ => None,
    }
}

fn unit_per_px(unit: CountUnit) -> &'static str {
    match unit {
        CountUnit::Cycles => "cycles/px",
        CountUnit::Instructions => "instr/px",
        CountUnit::Uncounted => "uncounted",
    }
}

fn short(row: &BenchRow) -> String {
    match &row.result {
        BenchResult::Measured(f) => format!(
            "{:.2} {} (floor {:.2})",
            per_pixel(row, f.engine_total),
            unit_per_px(row.unit),
            per_pixel(row, f.floor_total)
        ),
        BenchResult::DoesNotFit { limit } => format!("not measured: {limit}"),
        BenchResult::SlopesDiffer { window } => {
            format!("the engine's slopes differ from the floor's (window {window})")
        }
    }
}

/// The table: one line per workload.
pub fn table(board: &str, rows: &[BenchRow]) -> String {
    let mut out = String::new();
    let unit = rows.first().map_or(CountUnit::Uncounted, |r| r.unit);
    let clock = rows.iter().find_map(|r| r.clock_hz);
    let _ = writeln!(
        out,
        "{board}: {}{}",
        match unit {
            CountUnit::Cycles => "core clock cycles (DWT CYCCNT), caches on as the board runs",
            CountUnit::Instructions =>
                "instructions (QEMU -icount), NOT cycles: no caches, wait states or dual issue",
            CountUnit::Uncounted =>
                "UNCOUNTED: QEMU without -icount, the figures follow host time and mean nothing",
        },
        clock.map_or(String::new(), |hz| format!(
            " at {:.0} MHz",
            hz as f64 / 1e6
        ))
    );
    let _ = writeln!(
        out,
        "{:<34} {:>12} {:>9} {:>9} {:>7} {:>10} {:>10} {:>8}  floor check",
        "workload", "unit", "engine/px", "floor/px", "x floor", "last row", "floor row", "Mpx/s"
    );
    for row in rows {
        match &row.result {
            BenchResult::Measured(f) => {
                let (engine, floor) = (
                    per_pixel(row, f.engine_total),
                    per_pixel(row, f.floor_total),
                );
                let _ = writeln!(
                    out,
                    "{:<34} {:>12} {:>9.2} {:>9.2} {:>7.2} {:>10} {:>10} {:>8}  {}",
                    row.workload,
                    unit_per_px(row.unit),
                    engine,
                    floor,
                    if floor > 0.0 {
                        engine / floor
                    } else {
                        f64::NAN
                    },
                    f.engine_last_row.median,
                    f.floor_last_row.median,
                    mpx_per_s(row, f).map_or("-".to_string(), |m| format!("{m:.1}")),
                    match f.floor_check {
                        FloorCheck::Equal => "slopes equal",
                        FloorCheck::NotComparable => "other rule",
                    }
                );
            }
            other => {
                let text = match other {
                    BenchResult::DoesNotFit { limit } => format!("not measured: {limit}"),
                    BenchResult::SlopesDiffer { window } => format!(
                        "FAULT: the engine's slopes differ from the floor's (window {window})"
                    ),
                    BenchResult::Measured(_) => unreachable!(),
                };
                let _ = writeln!(out, "{:<34} {text}", row.workload);
            }
        }
    }
    let _ = writeln!(
        out,
        "(per px: over all measured frames; last row: median over the frames of the count from the frame's last camera row \
         arriving to its last result; x floor: the engine over the honest floor on the same frames in the same run{})",
        if unit == CountUnit::Cycles {
            "; Mpx/s: the engine alone at the board's clock"
        } else {
            ""
        }
    );
    out
}

fn spread_json(s: &Spread) -> serde_json::Value {
    json!({"min": s.min, "median": s.median, "max": s.max})
}

/// One workload as JSON.
pub fn row_json(row: &BenchRow) -> serde_json::Value {
    let unit = match row.unit {
        CountUnit::Cycles => "cycles",
        CountUnit::Instructions => "instructions",
        CountUnit::Uncounted => "uncounted",
    };
    let mut value = json!({
        "workload": row.workload,
        "unit": unit,
        "clock_hz": row.clock_hz,
        "pixels": row.pixels,
        "frames": row.frames,
    });
    let map = value.as_object_mut().expect("an object");
    match &row.result {
        BenchResult::Measured(f) => {
            let (engine, floor) = (
                per_pixel(row, f.engine_total),
                per_pixel(row, f.floor_total),
            );
            map.insert("measured".into(), json!(true));
            map.insert("engine_total".into(), json!(f.engine_total));
            map.insert("floor_total".into(), json!(f.floor_total));
            map.insert("engine_per_px".into(), json!(engine));
            map.insert("floor_per_px".into(), json!(floor));
            map.insert("x_floor".into(), json!(engine / floor));
            map.insert("engine_frame".into(), spread_json(&f.engine_frame));
            map.insert("engine_last_row".into(), spread_json(&f.engine_last_row));
            map.insert("floor_frame".into(), spread_json(&f.floor_frame));
            map.insert("floor_last_row".into(), spread_json(&f.floor_last_row));
            map.insert(
                "floor_check".into(),
                json!(match f.floor_check {
                    FloorCheck::Equal => "equal",
                    FloorCheck::NotComparable => "not_comparable",
                }),
            );
            map.insert("mpx_per_s".into(), json!(mpx_per_s(row, f)));
        }
        BenchResult::DoesNotFit { limit } => {
            map.insert("measured".into(), json!(false));
            map.insert("not_measured".into(), json!(limit.to_string()));
        }
        BenchResult::SlopesDiffer { window } => {
            map.insert("measured".into(), json!(false));
            map.insert("slopes_differ_window".into(), json!(window));
        }
    }
    value
}
