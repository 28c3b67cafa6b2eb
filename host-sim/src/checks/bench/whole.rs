//! `dncal bench --whole`: issue 17's targets that are whole commands on inputs of
//! gigabytes: `linearity` on a 1024 x 1024 x 41-level set, `diagnose` on a 2048 x 2048 x
//! 41-level set, and the demo. Each runs as a user runs it, the `dncal` binary in a process
//! of its own, measured by [`child::run_measured`](super::child::run_measured): wall time
//! from spawn to exit, and its own peak resident memory. The baselines are the issue's
//! limits, fixed numbers rather than runs in this process: a row's spread is the
//! command's own, and its ratio is the limit over the cost (at least 1: within the limit).
//! The one baseline that is a run is numpy's `linearity`, run once (85-91 s and 3.5 GB on
//! 1024 x 1024) against each of ours, which must agree with it.
//!
//! The sets are simulated first (not timed) by `dncal simulate linearity`, the default
//! camera sized to the set, into a temporary directory (3.4 GB of FITS at the issue's
//! sizes). That runs in child processes too, so that this process stays small and each
//! command's `ru_maxrss` is its own, exact (see [`super::child`]). Units: 1 KB is 1024
//! bytes, 1 GB 10^9 bytes. The limits are checked only at the issue's sizes, where they
//! were set (the demo's always).

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use super::child::{run_measured, Finished};
use super::{cost, numpy_linearity, ratio, Ratio};
use crate::infra::progress::stage;
use crate::HostError;

/// The issue's `linearity` set: 1024 x 1024 pixels, 2 frames a level (the frames only
/// change the simulation's time, not the analysis').
pub const LINEARITY_SIDE: usize = 1024;
const LINEARITY_FRAMES: u32 = 2;
/// `linearity`'s limits: wall seconds, and bytes a pixel resident beyond the input file;
/// its target against numpy (numpy's time over ours).
const LINEARITY_WALL_S: f64 = 2.0;
const LINEARITY_BYTES_A_PIXEL: f64 = 1024.0;
const LINEARITY_NUMPY: f64 = 10.0;
/// The issue's `diagnose` set: 2048 x 2048 pixels, 16 frames a level (as the sets of
/// docs/diagnose.md).
pub const DIAGNOSE_SIDE: usize = 2048;
const DIAGNOSE_FRAMES: u32 = 16;
/// `diagnose`'s limits: wall seconds, peak resident GB (10^9 bytes), and resident bytes a
/// pixel (the input included).
const DIAGNOSE_WALL_S: f64 = 300.0;
const DIAGNOSE_RSS_GB: f64 = 4.0;
const DIAGNOSE_BYTES_A_PIXEL: f64 = 1024.0;
/// The demo's limit, wall seconds.
const DEMO_WALL_S: f64 = 60.0;
/// The largest side the bench simulates: a 4096 x 4096 x 41-level set is 11 GB of FITS.
const MAX_SIDE: usize = 4096;

/// What the whole-command rows run.
#[derive(Debug, Clone)]
pub struct WholeParams {
    /// The `dncal` binary to run (the one running the bench).
    exe: PathBuf,
    /// Side of the `linearity` set, pixels.
    linearity_side: usize,
    /// Side of the `diagnose` set, pixels.
    diagnose_side: usize,
}

impl WholeParams {
    /// Checked before anything runs: each side from 8 to 4096 pixels, and a sensor the
    /// camera model accepts.
    pub fn new(exe: PathBuf, linearity_side: usize, diagnose_side: usize) -> Result<Self, HostError> {
        for (flag, side) in [("--linearity-side", linearity_side), ("--diagnose-side", diagnose_side)] {
            if !(8..=MAX_SIDE).contains(&side) {
                return Err(HostError::argument(flag, format!("a set's side must be 8 to {MAX_SIDE} pixels, not {side}")));
            }
            camera_of_side(side).validate().map_err(|e| HostError::argument(flag, e.to_string()))?;
        }
        Ok(WholeParams { exe, linearity_side, diagnose_side })
    }
}

/// The whole-command rows: `runs.min(3)` runs of `linearity` and of the demo, one of
/// `diagnose` (minutes at the issue's size).
pub fn rows(w: &WholeParams, runs: usize, numpy: bool, notes: &mut Vec<String>) -> Result<Vec<Ratio>, HostError> {
    let dir = tempfile::tempdir().map_err(|e| HostError::io(std::env::temp_dir(), e))?;
    let mut rows = linearity_rows(w, dir.path(), runs.min(3), numpy, notes)?;
    rows.extend(diagnose_rows(w, dir.path(), notes)?);
    rows.push(demo_row(w, dir.path(), runs.min(3), notes)?);
    Ok(rows)
}

/// The default camera at `side x side` pixels.
fn camera_of_side(side: usize) -> crate::model::camera::CameraConfig {
    crate::model::camera::CameraConfig { width: side, height: side, ..Default::default() }
}

/// A whole `side x side` sensor's 41-level set, simulated into `dir/name` by
/// `dncal simulate linearity` (its camera given as a TOML of the two sizes).
fn whole_sensor_set(w: &WholeParams, dir: &Path, name: &str, side: usize, frames: u32) -> Result<PathBuf, HostError> {
    stage(&format!("bench --whole: simulating a {side} x {side} x 41-level set ({frames} frames a level; not timed)"));
    let config = dir.join(format!("camera-{side}.toml"));
    std::fs::write(&config, format!("width = {side}\nheight = {side}\n")).map_err(|e| HostError::io(&config, e))?;
    let set = dir.join(name);
    let roi = format!("{side}x{side}+0+0");
    run_measured(&w.exe, &args(&[&"simulate", &"linearity", &"--config", &config, &"--roi", &roi, &"--frames", &frames.to_string(), &"-o", &set, &"-q"]))?;
    Ok(set)
}

/// Standard output as JSON, or an error naming the command.
fn json_of(what: &str, f: &Finished) -> Result<serde_json::Value, HostError> {
    serde_json::from_slice(&f.stdout).map_err(|e| HostError::Tool { program: what.into(), message: format!("its JSON report: {e}") })
}

/// A command line's arguments, of strings and paths alike.
fn args(list: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    list.iter().map(|a| a.as_ref().to_os_string()).collect()
}

/// A note where a process's peak memory was sampled (a lower bound) rather than exact.
fn note_sampled(what: &str, f: &Finished, notes: &mut Vec<String>) {
    if f.peak_sampled {
        notes.push(format!("{what}: peak memory {:.3} GB sampled every 10 ms (a lower bound): it stayed below this process's own", f.peak_rss as f64 / 1e9));
    }
}

/// `dncal linearity SET -q --json`: wall time, memory beyond the input file, and against
/// the same steps in numpy/astropy (whose largest pixel-wise RMS must equal ours).
fn linearity_rows(w: &WholeParams, dir: &Path, runs: usize, numpy: bool, notes: &mut Vec<String>) -> Result<Vec<Ratio>, HostError> {
    let side = w.linearity_side;
    let set = whole_sensor_set(w, dir, "linearity.fits", side, LINEARITY_FRAMES)?;
    let input = std::fs::metadata(&set).map_err(|e| HostError::io(&set, e))?.len();
    let pixels = (side * side) as f64;
    let (mut walls, mut beyond, mut pixelwise) = (Vec::new(), Vec::new(), Vec::new());
    for run in 1..=runs {
        stage(&format!("bench --whole: dncal linearity, run {run}/{runs}"));
        let f = run_measured(&w.exe, &args(&[&"linearity", &set, &"-q", &"--json"]))?;
        let v = json_of("dncal linearity", &f)?;
        pixelwise.push(v["rms_pixelwise_max"].as_f64().ok_or_else(|| HostError::Tool { program: "dncal linearity".into(), message: format!("no rms_pixelwise_max in its report: {v}") })?);
        note_sampled("dncal linearity", &f, notes);
        walls.push(f.wall_s);
        beyond.push(f.peak_rss.saturating_sub(input) as f64 / pixels);
    }
    let at_issue = side == LINEARITY_SIDE;
    let name = |what: &str| format!("linearity {side} x {side} x 41, {what}");
    let mut rows = vec![
        cost(&name("wall"), &walls, "issue 17: 2 s", LINEARITY_WALL_S, "s", at_issue.then_some(1.0)),
        cost(&name("beyond input"), &beyond, "issue 17: 1 KB a pixel", LINEARITY_BYTES_A_PIXEL, "B/px", at_issue.then_some(1.0)),
    ];
    if numpy {
        stage("bench --whole: the same steps in numpy/astropy, one run");
        match numpy_linearity(&set) {
            Ok((seconds, theirs)) => {
                if let Some(ours) = pixelwise.iter().find(|&&ours| !super::same_rms(ours, theirs)) {
                    return Err(HostError::Format { path: set, message: format!("linearity: numpy's largest pixel-wise RMS {theirs} differs from ours {ours}") });
                }
                let ours: Vec<f64> = walls.iter().map(|s| 1.0 / s).collect();
                rows.push(ratio(&name("whole process"), &ours, "numpy/astropy, same steps, 1 run", &vec![1.0 / seconds; ours.len()], "sets/s", at_issue.then_some(LINEARITY_NUMPY)));
            }
            Err(e) => notes.push(format!("numpy linearity ({side} x {side}) skipped: {e}")),
        }
    }
    Ok(rows)
}

/// `dncal diagnose SET -q --json` once, on the default memory budget: wall time, peak
/// resident memory, and that a pixel.
fn diagnose_rows(w: &WholeParams, dir: &Path, notes: &mut Vec<String>) -> Result<Vec<Ratio>, HostError> {
    let side = w.diagnose_side;
    let set = whole_sensor_set(w, dir, "diagnose.fits", side, DIAGNOSE_FRAMES)?;
    stage(&format!("bench --whole: dncal diagnose on {side} x {side} (minutes at 2048)"));
    let f = run_measured(&w.exe, &args(&[&"diagnose", &set, &"-q", &"--json"]))?;
    let v = json_of("dncal diagnose", &f)?;
    if !v.is_object() {
        return Err(HostError::Tool { program: "dncal diagnose".into(), message: format!("its report is not one set's: {v}") });
    }
    note_sampled("dncal diagnose", &f, notes);
    let at_issue = side == DIAGNOSE_SIDE;
    let name = |what: &str| format!("diagnose {side} x {side} x 41, {what}");
    let target = at_issue.then_some(1.0);
    Ok(vec![
        cost(&name("wall"), &[f.wall_s], "issue 17: 5 min", DIAGNOSE_WALL_S, "s", target),
        cost(&name("peak RSS"), &[f.peak_rss as f64 / 1e9], "issue 17: 4 GB", DIAGNOSE_RSS_GB, "GB", target),
        cost(&name("RSS a pixel"), &[f.peak_rss as f64 / (side * side) as f64], "issue 17: 1 KB a pixel", DIAGNOSE_BYTES_A_PIXEL, "B/px", target),
    ])
}

/// `dncal demo -q --json` on its defaults, its outputs in `dir`: wall time. A demo whose
/// check fails exits with 1 and says so only in its report: that is an error here.
fn demo_row(w: &WholeParams, dir: &Path, runs: usize, notes: &mut Vec<String>) -> Result<Ratio, HostError> {
    let mut walls = Vec::new();
    for run in 1..=runs {
        stage(&format!("bench --whole: dncal demo, run {run}/{runs}"));
        let out = dir.join(format!("demo-{run}"));
        let f = run_measured(&w.exe, &args(&[&"demo", &"-o", &out, &"-q", &"--json"]))?;
        json_of("dncal demo", &f)?;
        note_sampled("dncal demo", &f, notes);
        walls.push(f.wall_s);
    }
    Ok(cost("demo, defaults, wall", &walls, "issue 17: 60 s", DEMO_WALL_S, "s", Some(1.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row of costs: the limit over the cost, per run, and the target read on the median.
    #[test]
    fn a_cost_row_is_the_limit_over_the_cost() {
        let r = cost("x", &[1.0, 4.0, 2.0], "limit", 2.0, "s", Some(1.0));
        assert_eq!((r.ratio_median, r.ratio_min, r.ratio_max), (1.0, 0.5, 2.0));
        assert_eq!(r.rate, 2.0);
        assert_eq!(r.holds, Some(true));
        let r = cost("x", &[3.0], "limit", 2.0, "s", Some(1.0));
        assert_eq!(r.holds, Some(false));
    }

    /// Sides are checked before anything runs.
    #[test]
    fn sides_outside_the_range_are_refused() {
        let exe = PathBuf::from("dncal");
        assert!(WholeParams::new(exe.clone(), 8, MAX_SIDE).is_ok());
        for (l, d, flag) in [(7, 64, "--linearity-side"), (64, MAX_SIDE + 1, "--diagnose-side")] {
            let e = WholeParams::new(exe.clone(), l, d).unwrap_err().to_string();
            assert!(e.contains(flag) && e.contains("8 to 4096"), "{e}");
        }
    }
}
