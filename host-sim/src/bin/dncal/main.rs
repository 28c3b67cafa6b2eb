//! `dncal`: the command people run. Library code returns `HostError` and a
//! [`Report`]; this file dispatches the parsed arguments ([`cli`]), prints the report as
//! text or JSON (`--json`), and turns errors into a message on stderr and a nonzero exit.

mod cli;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use cli::{Cli, Cmd, ExportFormat, LutCmd, SimulateCmd};
use dncal_host::analyses::flatten::Recipe;
use dncal_host::model::camera::calibration::LinearityParams;
use dncal_host::checks::firmware::check::{firmware_check, CheckParams};
use dncal_host::analyses::quantization::run as quantization;
use dncal_host::analyses::{adc, diagnose::run as diagnose, emva::run as emva, fpga_size as fpga, kcor::run as kcor, linearity::run as linearity, lut::run as lut};
use dncal_host::checks::{bench, stream_run as stream};
use dncal_host::commands::demo;
use dncal_host::formats::report::Report;
use dncal_host::infra::progress;
use dncal_host::model::sets as simulate;
use dncal_host::formats::outputs::{staged, staged_in, Hold, Outputs};
use dncal_host::checks::streaming::StreamParams;
use dncal_host::HostError;

fn main() -> ExitCode {
    let cli = match parse() {
        Ok(cli) => cli,
        Err(e) => return usage_error(e),
    };
    // Before any thread starts; `diagnose` only, where it was measured to pay
    // (infra/allocator.rs).
    if matches!(cli.command, Cmd::Diagnose { .. }) {
        dncal_host::infra::allocator::reuse_freed_blocks();
    }
    // The outputs stay undoable until the report is on stdout: a report that cannot be
    // written (`--json > /dev/full`) leaves no outputs either (issue 43).
    let outputs = dncal_host::formats::outputs::hold();
    match run(cli, &outputs) {
        Ok(code) => {
            outputs.commit();
            code
        }
        Err(e) => {
            drop(outputs);
            // Bytes from files may be in it: escaped, never sent raw to the terminal.
            eprintln!("dncal: error: {}", dncal_host::infra::printable::printable(&e.to_string()));
            ExitCode::from(e.exit_code())
        }
    }
}

/// Runs the command and prints its report; the exit code is a failure where the command
/// ran but its check did not pass (`stream`, `demo`, `firmware-check`).
fn run(cli: Cli, outputs: &Hold) -> Result<ExitCode, HostError> {
    if let Some(bytes) = cli.max_memory {
        dncal_host::infra::budget::set_limit(bytes);
    }
    progress::set_quiet(cli.quiet);
    // No output may replace an input (issue 43): compared for the whole run.
    let _inputs = dncal_host::formats::same_file::watch();
    // Every file the command line names, checked (and claimed) before the command reads or
    // computes anything (issue 56).
    outputs.reserve(|files| declare_outputs(&cli.command, files))?;
    let passed = |ok: bool| if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE };
    match cli.command {
        Cmd::Simulate { what: SimulateCmd::Histograms { camera, ramp, out, json } } => print(json, &simulate::simulate_histograms(&camera.camera()?, &ramp.params()?, out)?)?,
        Cmd::Simulate { what: SimulateCmd::Linearity { camera, levels, frames, roi, seed, out, json } } => {
            let cam = camera.camera()?;
            let paper = LinearityParams::paper(&cam);
            let roi = roi.map_or(paper.roi, |r| {
                let (w, h, x, y) = r.parts();
                (x, y, w, h)
            });
            print(json, &simulate::simulate_linearity(&cam, &LinearityParams { levels, frames, roi, seed, ..paper }, out)?)?;
        }
        Cmd::Lut { what: LutCmd::Build { hist, out, flatten, truth, json } } => print(json, &lut::build(&hist, &out, &flatten.params(), truth.as_deref())?)?,
        Cmd::Lut { what: LutCmd::Import { kcor, out, json } } => print(json, &lut::import_kcor(&kcor, &out)?)?,
        Cmd::Lut { what: LutCmd::Export { lut: file, format: ExportFormat::Kcor, out, bits, json } } => print(json, &lut::export_kcor(&file, &out, bits)?)?,
        Cmd::Lut { what: LutCmd::Convert { lut: file, to, out, bits, json } } => print(json, &lut::convert(&file, to.into(), &out, bits)?)?,
        Cmd::Lut { what: LutCmd::Inspect { file, table, json } } => print(json, &lut::InspectSummary { list_codes: table, ..lut::inspect(&file)? })?,
        Cmd::Stream { camera, hist, flatten, frames, states, roi, seed, frames_from, engine, json } => {
            let cam = camera.camera()?;
            let p = StreamParams { states, seed, engine: engine.engine()?, ..StreamParams::full_frame(&cam, frames) };
            let p = stream::placed(&cam, p, roi, frames_from.as_deref())?;
            let r = stream::stream(&cam, hist.as_deref(), &flatten.params(), &p)?;
            print(json, &r)?;
            return Ok(passed(r.passed()));
        }
        Cmd::Adc { from_luts, out, json, .. } if !from_luts.is_empty() => print(json, &staged_in(&out, |o| adc::from_luts(&from_luts, o))?)?,
        Cmd::Adc { camera, hist, out, ramp, flatten, density, json, .. } => {
            let (cam, ramp) = (camera.camera()?, ramp.params()?);
            print(json, &staged_in(&out, |o| adc::run(&cam, hist.as_deref(), &ramp, &flatten.params(), density.density(), o))?.0)?;
        }
        Cmd::KcorModel { camera, adc, exposure_ms, steps, lut_noise, lut, limit_from, q_fraction, seed, realizations, out, json } => {
            let cam = camera.camera()?;
            let p = dncal_host::analyses::kcor::KcorParams { adc, exposure_s: exposure_ms * 1e-3, steps, lut_noise, q_fraction, seed, ..Default::default() };
            if limit_from.is_some() && realizations > 1 {
                return Err(HostError::argument("--realizations", "more than 1 only for the noisy LUT (not with --lut or --limit-from)"));
            }
            let spin = progress::spinner(&format!("K-Coronagraph model: ADC {adc}, {steps} steps of the Stokes map, {realizations} realization(s)"));
            match (lut.as_deref(), limit_from.as_deref()) {
                (Some(l), Some(h)) => {
                    let s = staged(out.as_deref(), |o| kcor::kcor_model_with_limit(&cam, &p, l, h, o));
                    spin.finish_and_clear();
                    print(json, &s?)?;
                }
                _ => {
                    let s = staged(out.as_deref(), |o| kcor::kcor_model(&cam, &p, lut.as_deref(), realizations, o));
                    spin.finish_and_clear();
                    print(json, &s?)?;
                }
            }
        }
        Cmd::Linearity { file, order, flat_level, held_out, out, json } => print(json, &staged(out.as_deref(), |o| linearity::linearity(&file, order, flat_level, &held_out, o))?)?,
        Cmd::Diagnose { files, flatten, seed, block_rows, spill, out, json } => match &diagnose::diagnose_files(&files, &diagnose::DiagnoseParams { flatten: flatten.params_or(Recipe::Paper), seed, block_rows: block_rows.map(|r| usize::try_from(r).unwrap_or(usize::MAX)), spill }, out.as_deref())?[..] {
            [one] => print(json, one)?,
            several => print(json, several)?,
        },
        Cmd::Quantization { sigma, read_noise_e, gain_e_per_dn, bias, figure, samples, json } => {
            let request = quantization::Request { sigma, read_noise_e, gain_e_per_dn, bias, figure, samples };
            print(json, &quantization::quantization(&request)?)?;
        }
        Cmd::Emva { descriptor, release, out, json } => print(json, &emva::emva(&descriptor, release, out.as_deref())?)?,
        Cmd::Completions { shell } => {
            // Into memory first: clap_complete panics on a failed write (a closed pipe).
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut command(), "dncal", &mut script);
            to_stdout(&script)?;
        }
        Cmd::Man { out } => man_pages(out.as_deref())?,
        Cmd::Demo { camera, out, frames, ramp, flatten, kcor_tables, json } => {
            let s = demo::demo(&camera.camera()?, &out, &ramp.params()?, &flatten.params(), frames, kcor_tables.as_deref())?;
            print(json, &s)?;
            return Ok(passed(s.passed()));
        }
        Cmd::FpgaSize { cameras, size, frame_rate, states, fifo_depth, mem_latency, lut, out, json } => {
            let config = dncal_fpga_model::Config { fifo_depth, mem_latency, ..Default::default() };
            let system = dncal_fpga_model::sizing::System { cameras, width: size, height: size, frame_rate_hz: frame_rate, ..Default::default() };
            print(json, &fpga::fpga_size(&system, states, &config, lut.as_deref(), out.as_deref())?)?;
        }
        Cmd::FirmwareCheck { frames_per_state, states, size, seed, count_instructions, json } => {
            let r = firmware_check(CheckParams { frames_per_state, states, size, seed, count_instructions })?;
            print(json, &r)?;
            return Ok(passed(r.ok));
        }
        Cmd::Bench { runs, frames, no_numpy, python, whole, linearity_side, diagnose_side, check, json } => {
            let params = bench::BenchParams { runs, frames, numpy: !no_numpy, python };
            params.check()?;
            let whole = match whole {
                true => Some(bench::whole::WholeParams::new(std::env::current_exe().map_err(|e| HostError::IoOf { subject: dncal_host::Subject::DncalBinary, source: e })?, linearity_side, diagnose_side)?),
                false => None,
            };
            // The whole commands first, while this process is small: a child's
            // `ru_maxrss` starts from its parent's high-water mark (`bench::child`).
            let mut whole_notes = Vec::new();
            let whole_rows = match &whole {
                Some(w) => bench::whole::rows(w, runs, !no_numpy, &mut whole_notes)?,
                None => Vec::new(),
            };
            let pb = progress::bar(bench::progress_steps(runs), "bench");
            let r = bench::bench(&params, |_| pb.inc(1));
            pb.finish_and_clear();
            let mut r = r?;
            r.ratios.extend(whole_rows);
            r.notes.extend(whole_notes);
            if check {
                r.check = Some(bench::ratchet::check(&r));
            }
            print(json, &r)?;
            return Ok(passed(r.check.as_ref().is_none_or(|c| c.holds())));
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Names the files `command` writes that its command line alone determines, for
/// [`Hold::reserve`]: one check of every command's outputs, before it reads or computes
/// anything (issue 56; each command names the same files again when it writes them, and
/// takes over these claims). Files named by what an input holds are claimed by the
/// command itself as soon as it has read that input, before it computes: one figure per
/// ADC of `adc --hist`'s histogram set (of the camera's ADCs when simulated), the files of
/// each camera of `adc --from-luts`, the histogram test figures of each histogram set
/// `diagnose` reads; and the figure of each of a diagnosis's findings only once found.
fn declare_outputs(command: &Cmd, files: &mut Outputs) -> Result<(), HostError> {
    use dncal_host::formats::lut::{output_paths, LutFormat, LutOutputs};
    let lut_pair = |files: &mut Outputs, out: &Path| {
        let pair = LutOutputs::for_prefix(out)?;
        files.expect([pair.fits, pair.image])
    };
    match command {
        Cmd::Simulate { what: SimulateCmd::Histograms { out, .. } | SimulateCmd::Linearity { out, .. } } => files.expect([out]),
        Cmd::Lut { what: LutCmd::Build { out, .. } | LutCmd::Import { out, .. } } => lut_pair(files, out),
        Cmd::Lut { what: LutCmd::Export { format: ExportFormat::Kcor, out, .. } } => files.expect(output_paths(LutFormat::Kcor, Path::new(out))?),
        Cmd::Lut { what: LutCmd::Convert { to, out, .. } } => files.expect(output_paths((*to).into(), out)?),
        Cmd::Adc { from_luts, out, .. } if !from_luts.is_empty() => adc::expect_from_luts(files, out),
        Cmd::Adc { hist, out, .. } => adc::expect_run(files, out, hist.is_none(), None),
        Cmd::KcorModel { out, .. } => out.as_deref().map_or(Ok(()), |dir| kcor::expect_figures(files, dir)),
        Cmd::Linearity { out, .. } => out.as_deref().map_or(Ok(()), |dir| linearity::expect_report(files, dir)),
        Cmd::Diagnose { files: inputs, out, .. } => out.as_deref().map_or(Ok(()), |dir| diagnose::expect_reports(files, inputs.len(), dir)),
        Cmd::Emva { out, .. } => out.as_deref().map_or(Ok(()), |dir| dncal_host::analyses::emva::html::expect_datasheet(files, dir)),
        Cmd::FpgaSize { lut: Some(_), out: Some(dir), .. } => fpga::expect_readmemh(files, dir),
        Cmd::FpgaSize { .. } => Ok(()),
        Cmd::Quantization { figure, .. } => files.expect(figure),
        Cmd::Man { out } => out.as_deref().map_or(Ok(()), |dir| {
            files.create_dir(dir)?;
            files.expect(man_pages_in(dir).into_iter().map(|(path, _)| path))
        }),
        Cmd::Demo { out, .. } => demo::expect_outputs(files, out, None),
        // No files: reports on stdout only.
        Cmd::Lut { what: LutCmd::Inspect { .. } } | Cmd::Stream { .. } | Cmd::FirmwareCheck { .. } | Cmd::Bench { .. } | Cmd::Completions { .. } => Ok(()),
    }
}

/// The report as JSON (`--json`) or as its readable text, on stdout. The JSON is written
/// as it is serialized, never held: it grows with the input (a histogram set's residuals
/// and tests, 116 bytes a count: 122 MB for 256 ADCs), and held whole it doubled the peak
/// of `diagnose --json` beyond what the memory budget counts (issue 56). It is serialized
/// into nothing first, so that a report that does not serialize leaves stdout empty.
fn print(json: bool, report: &(impl Report + ?Sized)) -> Result<(), HostError> {
    if !json {
        return to_stdout(report.text().as_bytes());
    }
    serde_json::to_writer_pretty(std::io::sink(), report).map_err(|e| HostError::invalid(dncal_host::Subject::Stdout, e.to_string()))?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    // Serialized once already: what fails now is the writing (the original I/O error).
    let written = serde_json::to_writer_pretty(&mut out, report).map_err(std::io::Error::from).and_then(|()| out.write_all(b"\n")).and_then(|()| out.flush());
    match written {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(HostError::IoOf { subject: dncal_host::Subject::Stdout, source: e }),
        _ => Ok(()),
    }
}

/// Writes `bytes` to stdout; a closed pipe (`dncal ... | head`) is the reader's choice,
/// not an error.
fn to_stdout(bytes: &[u8]) -> Result<(), HostError> {
    match std::io::stdout().lock().write_all(bytes) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(HostError::IoOf { subject: dncal_host::Subject::Stdout, source: e }),
        _ => Ok(()),
    }
}

/// The command line as clap reads it, negative numbers taken as values everywhere
/// (`--sigma -1`, not an unknown flag `-1`).
fn command() -> clap::Command {
    fn negatives(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(negatives)
    }
    negatives(<Cli as clap::CommandFactory>::command())
}

fn parse() -> Result<Cli, clap::Error> {
    let matches = command().try_get_matches()?;
    dncal_host::formats::fits::record_parameters(effective_parameters(&matches));
    <Cli as clap::FromArgMatches>::from_arg_matches(&matches)
}

/// Every argument's value as the command runs with it, defaults included and marked:
/// `subcommand: name=value name=value (default) ...`, for the FITS files' HISTORY (the
/// command line alone does not say what the defaults were).
fn effective_parameters(matches: &clap::ArgMatches) -> String {
    let (mut path, mut parts) = (Vec::new(), Vec::new());
    // A global argument (`--quiet`, `--max-memory`) is in every level's matches: once.
    let mut seen = std::collections::HashSet::new();
    let mut m = matches;
    loop {
        for id in m.ids().filter(|id| seen.insert(id.as_str().to_string())) {
            // A group's id has no values of its own (an error here, not a panic).
            let Ok(Some(values)) = m.try_get_raw(id.as_str()) else { continue };
            let values: Vec<String> = values.map(|v| v.to_string_lossy().into_owned()).collect();
            let default = m.value_source(id.as_str()) == Some(clap::parser::ValueSource::DefaultValue);
            parts.push(format!("{id}={}{}", values.join(","), if default { " (default)" } else { "" }));
        }
        match m.subcommand() {
            Some((name, sub)) => {
                path.push(name.to_string());
                m = sub;
            }
            None => break,
        }
    }
    format!("{}: {}", path.join(" "), parts.join(" "))
}

/// `dncal man`: the top page on stdout, or every page into `out`.
fn man_pages(out: Option<&Path>) -> Result<(), HostError> {
    fn render(cmd: &clap::Command) -> Result<Vec<u8>, HostError> {
        let mut page = Vec::new();
        clap_mangen::Man::new(cmd.clone()).render(&mut page).map_err(|e| HostError::IoOf { subject: dncal_host::Subject::ManPage, source: e })?;
        Ok(page)
    }
    let Some(dir) = out else {
        let mut cmd = command();
        cmd.build();
        return to_stdout(&render(&cmd)?);
    };
    let mut files = Outputs::new();
    files.create_dir(dir)?;
    for (path, cmd) in man_pages_in(dir) {
        files.write_bytes(&path, render(&cmd)?)?;
    }
    let written = files.publish()?;
    to_stdout(format!("wrote {} manual pages into {}\n", written.len(), dir.display()).as_bytes())
}

/// Every manual page `man -o DIR` writes: the command and each subcommand, named by its
/// path (`DIR/dncal-lut-build.1`, as git's are), with the command it renders.
fn man_pages_in(dir: &Path) -> Vec<(PathBuf, clap::Command)> {
    fn walk(cmd: &clap::Command, name: String, dir: &Path, pages: &mut Vec<(PathBuf, clap::Command)>) {
        pages.push((dir.join(format!("{name}.1")), cmd.clone().name(name.clone())));
        for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
            walk(sub, format!("{name}-{}", sub.get_name()), dir, pages);
        }
    }
    let mut cmd = command();
    cmd.build();
    let mut pages = Vec::new();
    walk(&cmd, "dncal".into(), dir, &mut pages);
    pages
}

/// clap's help and version as clap prints them; its usage errors in the one-line format
/// of every other error, exit code 2 (bad data is exit 1), naming the subcommand whose
/// `--help` explains: `dncal: error: invalid value 'abc' for '--sigma <SIGMA>': invalid
/// float literal (see dncal quantization --help)`.
fn usage_error(e: clap::Error) -> ExitCode {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
        let _ = e.print();
        return ExitCode::SUCCESS;
    }
    // A command given without its subcommand: its help, on stderr, exit 2 (as clap does).
    if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        let _ = e.print();
        return ExitCode::from(2);
    }
    let text = e.render().to_string();
    // The error is what precedes the first blank line (a missing-arguments error lists
    // them on the lines below its first); the rest is usage and tips.
    let message: Vec<&str> = text.lines().take_while(|l| !l.trim().is_empty()).map(str::trim).collect();
    let message = message.join(" ");
    let message = message.trim_start_matches("error: ");
    // clap's "tip: a similar subcommand exists" is below the blank line: kept, in one line.
    let suggested = [ContextKind::SuggestedSubcommand, ContextKind::SuggestedArg].into_iter().find_map(|kind| match e.get(kind) {
        Some(ContextValue::String(s)) => Some(vec![s.clone()]),
        Some(ContextValue::Strings(v)) if !v.is_empty() => Some(v.clone()),
        _ => None,
    });
    let tip = suggested.map_or(String::new(), |v| format!("; did you mean {}?", v.iter().map(|s| format!("'{s}'")).collect::<Vec<_>>().join(" or ")));
    // The subcommand path: the words of the command line that name subcommands.
    let mut cmd = command();
    let mut path = vec!["dncal".to_string()];
    // (`args_os`: an argument that is not Unicode must not panic here.)
    for word in std::env::args_os().skip(1) {
        let Some(sub) = word.to_str().and_then(|w| cmd.find_subcommand(w)).cloned() else { continue };
        path.push(sub.get_name().to_string());
        cmd = sub;
    }
    eprintln!("dncal: error: {}{} (see {} --help)", dncal_host::infra::printable::printable(message), dncal_host::infra::printable::printable(&tip), path.join(" "));
    ExitCode::from(2)
}
