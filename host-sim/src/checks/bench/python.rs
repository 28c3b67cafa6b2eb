//! The Python package's two speed ratios (issue 41) as rows of the bench: `--python PY`
//! runs `python/bench/speed.py` (built into the binary) with the interpreter `PY`, which
//! must import the `dncal` package (a release wheel: `scripts/python-bench.sh` makes one
//! in `target/python-bench-venv`). The script alternates the Python call and the
//! reference in its one process; here each run's pair becomes a ratio of rates.

use std::path::Path;
use std::process::Command;

use super::{child, ratio, Ratio};

/// The benchmark script.
const SPEED: &str = include_str!("../../../../python/bench/speed.py");

/// The target of both rows: within 1.2x of the reference's time.
const TARGET: f64 = 1.0 / 1.2;

/// Why the Python rows did not run (a note instead).
#[derive(Debug, thiserror::Error)]
pub enum PythonSkipped {
    #[error("python rows skipped: {0} did not start: {1}")]
    Spawn(String, std::io::Error),
    #[error("python rows skipped: {0}")]
    Failed(String),
    #[error("python rows skipped: speed.py printed {0}")]
    Output(String),
}

/// The rows of `speed.py`'s output: the correction rows' per-run Mpx/s against the core's,
/// and the fit's sets per second against `dncal linearity`'s analysis.
pub fn rows_of(out: &serde_json::Value) -> Option<Vec<Ratio>> {
    let times = |v: &serde_json::Value, k: &str| -> Option<Vec<f64>> { v[k].as_array()?.iter().map(|x| x.as_f64().filter(|s| *s > 0.0)).collect() };
    let mut rows = Vec::new();
    for c in out["correction"].as_array()? {
        let pixels = c["pixels"].as_f64()?;
        let rate = |s: Vec<f64>| s.into_iter().map(|t| pixels / t / 1e6).collect::<Vec<_>>();
        let (a, b) = (rate(times(c, "a_s")?), rate(times(c, "b_s")?));
        let name = format!("Python {}", c["what"].as_str()?.split(" / ").next()?);
        let what = c["what"].as_str()?.split(", ").skip(1).collect::<Vec<_>>().join(", ");
        rows.push(ratio(&format!("{name}, {what}"), &a, "the core's Corrector, same frames", &b, "Mpx/s", Some(TARGET)));
    }
    let l = &out["linearity"];
    let per_s = |s: Vec<f64>| s.into_iter().map(|t| 1.0 / t).collect::<Vec<_>>();
    let (a, b) = (per_s(times(l, "a_s")?), per_s(times(l, "b_s")?));
    let what = l["what"].as_str()?.split(", ").skip(1).collect::<Vec<_>>().join(", ");
    rows.push(ratio(&format!("Python fit_linearity, {what}"), &a, "dncal linearity's analysis", &b, "fits/s", Some(TARGET)));
    Some(rows)
}

/// Runs `speed.py` with `python` on the linearity set `set`, `runs` pairs per row.
pub fn python_ratios(python: &Path, set: &Path, runs: usize) -> Result<Vec<Ratio>, PythonSkipped> {
    let out = Command::new(python)
        .arg("-c")
        .arg(SPEED)
        .arg(set)
        .args(["--runs", &runs.to_string()])
        .output()
        .map_err(|e| PythonSkipped::Spawn(python.display().to_string(), e))?;
    if !out.status.success() {
        return Err(PythonSkipped::Failed(child::last_line(&out.stderr).unwrap_or_else(|| format!("{} failed", python.display()))));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|_| PythonSkipped::Output(text.chars().take(200).collect()))?;
    rows_of(&v).ok_or_else(|| PythonSkipped::Output(text.chars().take(200).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_output_becomes_rate_ratios_against_the_target() {
        // Python 1.25x the core's time on every run: 0.8 of its rate, under the 1/1.2
        // target; the fit at 1.1x: 0.909, over it.
        let v = serde_json::json!({
            "correction": [{"what": "Corrector.add / core, 1 frame(s) of 1024 x 1024 a call, 4 states", "pixels": 1048576.0, "a_s": [1.25e-3, 2.5e-3], "b_s": [1e-3, 2e-3]}],
            "linearity": {"what": "fit_linearity / dncal linearity analysis, 256 x 256 pixels, 41 levels", "a_s": [0.11, 0.22], "b_s": [0.1, 0.2]}
        });
        let rows = rows_of(&v).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].name, "Python Corrector.add, 1 frame(s) of 1024 x 1024 a call, 4 states");
        assert!((rows[0].ratio_median - 0.8).abs() < 1e-12 && rows[0].holds == Some(false));
        // The row's rate is the median of the runs' rates (of two: their mean), Mpx/s.
        let want = (1048576.0 / 1.25e-3 + 1048576.0 / 2.5e-3) / 2.0 / 1e6;
        assert!((rows[0].rate - want).abs() < 1e-9, "{} vs {want}", rows[0].rate);
        assert!((rows[1].ratio_median - 1.0 / 1.1).abs() < 1e-12 && rows[1].holds == Some(true));
        assert!(rows_of(&serde_json::json!({"correction": []})).is_none());
    }
}
