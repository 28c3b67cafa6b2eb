//! The soak (issue 18, `scripts/soak.sh`): at least 10^9 pixels through the core and the
//! FPGA model, every sum checked against the float reference; see `dncal_host::checks::soak`.
//! Prints a summary (and the whole report with `--json`); exits 1 if any check failed.

use clap::Parser;
use dncal_host::checks::soak::{run, SoakParams};

#[derive(Parser)]
#[command(about = "Stream frames through the core and the FPGA model, every sum checked against the float reference")]
struct Args {
    /// Pixels through the core (and as many through the FPGA model).
    #[arg(long, default_value_t = 1_000_000_000)]
    pixels: u64,
    /// Seed of everything random.
    #[arg(long, default_value_t = 18)]
    seed: u64,
    /// Side of the square region the ROIs are cut from (1 to 1024).
    #[arg(long, default_value_t = 1024)]
    sensor: u16,
    /// The core only.
    #[arg(long)]
    no_fpga: bool,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    json: bool,
}

fn main() {
    let args = Args::parse();
    let params = SoakParams { pixels: args.pixels, seed: args.seed, fpga: !args.no_fpga, sensor: args.sensor };
    // The command's own bar: shown only on a terminal, cleared when done.
    let bar = dncal_host::infra::progress::bar(args.pixels, "soak pixels");
    let result = run(&params, |done| bar.set_position(done.min(args.pixels)));
    bar.finish_and_clear();
    let report = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("soak: {e}");
            std::process::exit(1);
        }
    };
    if args.json {
        match serde_json::to_string_pretty(&report) {
            Ok(s) => println!("{s}"),
            Err(e) => eprintln!("soak: JSON: {e}"),
        }
    }
    eprintln!(
        "soak seed {}: {} segments, {} frames, {} pixels through the core, {} through the FPGA model, {} sums checked in {:.0} s",
        report.seed, report.segments, report.frames, report.pixels_core, report.pixels_fpga, report.sums_checked, report.wall_s
    );
    eprintln!(
        "  mismatches: core {}, FPGA {}, out of bound {}, counters {}; largest error {:.3e} DN",
        report.mismatches_core, report.mismatches_fpga, report.out_of_bound, report.counter_mismatches, report.max_abs_err_dn
    );
    eprintln!(
        "  LUT swaps {} ({} asked mid-frame, {} chunked uploads), corrupt images refused: core {}, FPGA {}; FPGA uploads {}",
        report.lut_swaps, report.mid_frame_activations, report.chunked_uploads, report.corrupt_images_refused, report.fpga_corrupt_refused, report.fpga_uploads
    );
    eprintln!("  clipped additions {}, saturated sums {}, out-of-range codes {}", report.saturated_additions, report.saturated_sums, report.out_of_range_codes);
    for f in &report.failures {
        eprintln!("  FAILED: {f}");
    }
    if !report.passed() {
        eprintln!("soak: FAILED");
        std::process::exit(1);
    }
    eprintln!("soak: passed");
}
