//! Inputs that are not what a command expects, as a user gives them (issue 18: never
//! panic, never hang, never lose a file): devices, FIFOs and oversized files where a file
//! is read, TOML mistakes, FITS headers that declare more than the file holds, and `-o`
//! naming a directory where a file prefix is expected. Each must be one line
//! `dncal: error: FILE: problem`, exit code 1, promptly, with nothing written.

mod support;

use std::process::Command;

use support::{assert_clean_failure, assert_error, dncal_prompt as dncal, flat_histograms, listing};

/// A missing or unreadable input is named in the system's words, without Rust's
/// "(os error 2)" (issue 44).
#[cfg(unix)]
#[test]
fn a_missing_input_is_said_in_plain_words() {
    let d = tempfile::tempdir().unwrap();
    assert_error(&dncal(&["lut", "inspect", "nothere.fits"], d.path()), "nothere.fits: no such file or directory");
    assert_error(&dncal(&["diagnose", "gone/set.fits"], d.path()), "gone/set.fits: no such file or directory");
}

#[cfg(unix)]
#[test]
fn devices_and_fifos_given_as_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A FIFO nobody writes to: opening it for reading blocks unless the open is
    // non-blocking.
    let made = Command::new("mkfifo").arg(d.join("in.fifo")).status().expect("mkfifo runs");
    assert!(made.success());
    std::fs::create_dir(d.join("folder")).unwrap();
    let kinds = [("/dev/zero", "character device"), ("/dev/urandom", "character device"), ("in.fifo", "FIFO"), ("folder", "directory")];
    for (input, kind) in kinds {
        let before = listing(d);
        let cases: [&[&str]; 10] = [
            &["lut", "inspect", input],
            &["simulate", "histograms", "--config", input, "-o", "h.fits"],
            &["emva", input],
            &["lut", "build", input, "-o", "cal"],
            &["linearity", input],
            &["diagnose", input],
            &["stream", "--frames-from", input],
            &["kcor-model", "--lut", input],
            &["lut", "import", "--kcor", input, input, input, input, "-o", "cal"],
            &["fpga-size", "--lut", input, "-o", "mem"],
        ];
        for args in cases {
            let out = dncal(args, d);
            assert_error(&out, &format!("{input}: is a {kind}, not a regular file"));
            assert_eq!(listing(d), before, "{args:?} wrote something");
        }
    }
}

#[test]
fn inputs_larger_than_their_kind_are_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Sparse: 17 MiB of zeros that cost nothing to make.
    for (name, len) in [("big.toml", 17u64 << 20), ("big.txt", 5 << 20)] {
        std::fs::File::create(d.join(name)).unwrap().set_len(len).unwrap();
    }
    let out = dncal(&["simulate", "histograms", "--config", "big.toml", "-o", "h.fits"], d);
    assert_error(&out, "big.toml: 17825792 bytes; camera config files are at most 16777216 bytes");
    let out = dncal(&["emva", "big.txt"], d);
    assert_error(&out, "big.txt: 5242880 bytes; EMVA 1288 descriptor files are at most 4194304 bytes");
    assert!(!d.join("h.fits").exists());
}

#[test]
fn toml_errors_are_one_line_with_the_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases = [
        ("syntax.toml", "name = \"cam\"\nread_noise_e = \n", "syntax.toml: line 2, column 16: invalid string; expected `\"`, `'`"),
        ("type.toml", "# a comment\n\nbits = \"twelve\"\n", "type.toml: line 3, column 8: invalid type: string \"twelve\", expected u32"),
        ("table.toml", "[adc]\nstage_bits = [3, 3, 3, 3]\nseed = -1\n", "table.toml: line 3, column 8: invalid value: integer `-1`, expected u64"),
    ];
    for (name, text, line) in cases {
        std::fs::write(d.join(name), text).unwrap();
        assert_error(&dncal(&["simulate", "histograms", "--config", name, "-o", "h.fits"], d), line);
    }
    // An unknown field lists the known ones, still on one line.
    std::fs::write(d.join("typo.toml"), "read_nois_e = 3.0\n").unwrap();
    let out = dncal(&["simulate", "histograms", "--config", "typo.toml", "-o", "h.fits"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: typo.toml: line 1, column 1: unknown field `read_nois_e`, expected one of `name`, "), "{stderr}");
    assert_eq!((stderr.lines().count(), out.status.code()), (1, Some(1)), "{stderr}");
    assert!(!d.join("h.fits").exists());
}

/// The offset of the first 80-byte header card `key` from `from` on, and its integer
/// value (0 for a card without one, such as END).
fn card(bytes: &[u8], from: usize, key: &str) -> (usize, i64) {
    let at = (from..bytes.len()).step_by(80).find(|&i| bytes[i..i + 8] == *format!("{key:<8}").as_bytes()).unwrap_or_else(|| panic!("no {key} card"));
    let value = std::str::from_utf8(&bytes[at + 10..at + 30]).unwrap().trim().parse().unwrap_or(0);
    (at, value)
}

#[test]
fn a_heap_larger_than_the_file_is_refused_naming_the_hdu() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(dncal(&["simulate", "linearity", "--levels", "12", "--frames", "4", "--roi", "16x16+0+0", "-o", "lin.fits"], d).status.success());
    // The file as written is read: what fails below is the patched PCOUNT.
    assert!(dncal(&["linearity", "lin.fits"], d).status.success());
    assert!(dncal(&["diagnose", "lin.fits"], d).status.success());
    let mut bytes = std::fs::read(d.join("lin.fits")).unwrap();
    // The REFERENCE table, the file's last HDU: PCOUNT (its heap) set to 2e9 bytes.
    let table = (0..bytes.len()).step_by(2880).find(|&i| bytes[i..].starts_with(b"XTENSION= 'BINTABLE'")).unwrap();
    let hdu = (0..table).step_by(2880).filter(|&i| bytes[i..].starts_with(b"XTENSION=")).count() + 1;
    let (pcount, zero) = card(&bytes, table, "PCOUNT");
    assert_eq!(zero, 0);
    bytes[pcount + 10..pcount + 30].copy_from_slice(format!("{:>20}", 2_000_000_000).as_bytes());
    std::fs::write(d.join("heap.fits"), &bytes).unwrap();
    // Where the table's heap would end, from the standard: header blocks, then rows x
    // row bytes + PCOUNT in whole blocks.
    let (end_card, _) = card(&bytes, table, "END");
    let data_start = (end_card / 2880 + 1) * 2880;
    let (_, row_bytes) = card(&bytes, table, "NAXIS1");
    let (_, rows) = card(&bytes, table, "NAXIS2");
    let end = data_start as u64 + ((row_bytes * rows) as u64 + 2_000_000_000).div_ceil(2880) * 2880;
    let line = format!(
        "heap.fits: the HDU {hdu} (REFERENCE) declares its header, data and heap (PCOUNT) to end at byte {end}; the file has {} bytes (truncated?)",
        bytes.len()
    );
    for args in [&["linearity", "heap.fits"][..], &["diagnose", "heap.fits", "-o", "report"]] {
        assert_error(&dncal(args, d), &line);
    }
    assert!(!d.join("report").exists());
}

#[test]
fn an_output_prefix_naming_a_directory_is_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    std::fs::create_dir(d.join("out")).unwrap();
    assert!(dncal(&["lut", "build", "h.fits", "-o", "cal"], d).status.success());
    let before = listing(d);
    let builds = [
        ("out/", "out/: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o out/cal)"),
        ("out", "out: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o out/cal)"),
        ("new/", "new/: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o new/cal)"),
    ];
    for (out, line) in builds {
        assert_error(&dncal(&["lut", "build", "h.fits", "-o", out], d), line);
    }
    let line = "out/: names a directory; -o takes a file prefix OUT and writes OUT_adc0.bin .. OUT_adc3.bin (e.g. -o out/cal)";
    assert_error(&dncal(&["lut", "export", "--format", "kcor", "cal.fits", "-o", "out/"], d), line);
    assert_eq!(listing(d), before);
    assert!(listing(&d.join("out")).is_empty());
    // A prefix inside the directory is what was meant, and works.
    assert!(dncal(&["lut", "build", "h.fits", "-o", "out/cal"], d).status.success());
    assert_eq!(listing(&d.join("out")), [d.join("out/cal.bin"), d.join("out/cal.fits")]);
}

/// A gzip file of two members: a FITS header declaring 4000 x 4000 16-bit pixels and
/// `zeros` bytes of data, then a member of 300,000 zero bytes, whose trailer is all a
/// reader of the last 4 bytes sees (cfitsio's estimate of the inflated size).
fn two_member_gzip(path: &std::path::Path, zeros: usize) {
    use std::io::Write;
    let cards = ["SIMPLE  =                    T", "BITPIX  =                   16", "NAXIS   =                    2", "NAXIS1  =                 4000", "NAXIS2  =                 4000", "END"];
    let mut header: Vec<u8> = cards.iter().flat_map(|c| format!("{c:<80}").into_bytes()).collect();
    header.resize(2880, b' ');
    let mut bytes = Vec::new();
    for member in [[header, vec![0u8; zeros]].concat(), vec![0u8; 300_000]] {
        let mut z = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        z.write_all(&member).unwrap();
        bytes.extend(z.finish().unwrap());
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn sizes_over_the_memory_budget_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A gzip file inflating to 16 MB whose trailer declares 300,000 bytes: within the
    // compression bound, so only counting the inflated bytes finds it over 4 MiB.
    two_member_gzip(&d.join("bomb.fits.gz"), 16 << 20);
    let before = listing(d);
    for args in [&["diagnose", "bomb.fits.gz"][..], &["lut", "inspect", "bomb.fits.gz"], &["linearity", "bomb.fits.gz"]] {
        let out = dncal(&[args, &["--max-memory", "4M"]].concat(), d);
        assert_error(&out, "bomb.fits.gz: inflates to more than 4.0 MiB (gzip), more than the memory budget (--max-memory)");
    }
    // Its 16 MB (within the default budget) inflate and reach the reader, which finds
    // the data cut short: the budget, not the count, refused it above.
    // (Issue 43: the header's declarations are held to the size counted.)
    let out = dncal(&["lut", "inspect", "bomb.fits.gz"], d);
    assert_error(&out, &format!("bomb.fits.gz: the primary HDU declares its header, data and heap (PCOUNT) to end at byte {}; the file inflates to {} bytes (truncated?)", 2880 + (2 * 4000 * 4000usize).div_ceil(2880) * 2880, 2880 + (16 << 20) + 300_000));

    // A histogram set of 4000 ADCs of 4096 codes: `lut build` refuses it from its header
    // (the core takes at most 8 ADCs), and `diagnose` its counts as read (24 bytes a
    // count) and their analysis (104), 2 GiB, by a budget of 64 MiB, both before cfitsio
    // reads a count (issue 56). A plain file.
    let cards = ["SIMPLE  =                    T", "BITPIX  =                    8", "NAXIS   =                    2", "NAXIS1  =                 4096", "NAXIS2  =                 4000", "BITDEPTH=                   12", "NADC    =                 4000", "ADCMAP  = 'COLMOD'", "END"];
    let mut plain: Vec<u8> = cards.iter().flat_map(|c| format!("{c:<80}").into_bytes()).collect();
    plain.resize(2880, b' ');
    plain.resize(2880 + 4096 * 4000, 0);
    plain.resize(plain.len().div_ceil(2880) * 2880, 0);
    std::fs::write(d.join("wide.fits"), &plain).unwrap();
    let out = dncal(&["--max-memory", "64M", "lut", "build", "wide.fits", "-o", "cal"], d);
    assert_error(&out, "wide.fits: 4000 ADCs of 4096 codes: the core is built for 1, 2, 4 or 8 ADCs of 8, 10, 12, 14 or 16 bits (8 ADCs up to 12 bits)");
    let out = dncal(&["--max-memory", "64M", "diagnose", "wide.fits"], d);
    assert_error(&out, "wide.fits: diagnosing the histogram set of 4000 ADCs of 4096 codes (the counts as read 375.0 MiB + their analysis 1.6 GiB) needs about 2.0 GiB, more than the memory budget of 64.0 MiB (--max-memory)");

    // A linearity set of 16 x 8 pixels x 12 levels, counted from its header before either
    // cube is read (issue 56): the cubes (16 bytes a value, 24 KiB), the corrected cube
    // the outputs write (8 bytes a value, 12 KiB) and the fits (152 + 8 (order + 1) bytes
    // a pixel, 24 KiB), 60 KiB; without outputs no corrected cube, and the fits 8 bytes a
    // pixel more on each thread (a level's row of scratch): the message's last part
    // depends on the machine.
    support::small_linearity(d, "lin.fits");
    let out = dncal(&["linearity", "lin.fits", "--max-memory", "56K", "-o", "lin_out"], d);
    assert_error(&out, "lin.fits: linearity of 16 x 8 pixels x 12 levels (the two cubes as read 24.0 KiB + the corrected cube 12.0 KiB + the fits 24.0 KiB) needs about 60.0 KiB, more than the memory budget of 56.0 KiB (--max-memory)");
    let out = dncal(&["linearity", "lin.fits", "--max-memory", "40K"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: lin.fits: linearity of 16 x 8 pixels x 12 levels (the two cubes as read 24.0 KiB + the fits ") && stderr.ends_with(", more than the memory budget of 40.0 KiB (--max-memory)\n"), "{stderr}");
    assert_eq!((out.status.code(), stderr.lines().count()), (Some(1), 1));
    let out = dncal(&["linearity", "lin.fits", "--max-memory", "128K", "--json"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // diagnose: 469 bytes per pixel beyond the set, 58.6 KiB (spilling its records would
    // take more here: a block of each kind per thread), and the illumination fit's sums
    // and fields, 1.6 MiB (65 tasks' sums of 12 levels x 2 halves x 64 bins of 16 bytes,
    // and 16; 15 modes), refused before the set is read by rows.
    let out = dncal(&["diagnose", "lin.fits", "--max-memory", "40K"], d);
    assert_error(&out, "lin.fits: diagnosing the linearity set of 16 x 8 pixels x 12 levels by rows (the per-pixel records 58.6 KiB + the illumination fit 1.6 MiB) needs about 1.7 MiB, more than the memory budget of 40.0 KiB (--max-memory)");

    // A camera config: 4096 x 4096 pixels of 17 bytes or more (gain, dark, state and the
    // nonlinearity terms) is more than 256 MiB.
    std::fs::write(d.join("cam.toml"), "width = 4096\nheight = 4096\n").unwrap();
    let out = dncal(&["simulate", "linearity", "--config", "cam.toml", "--max-memory", "256M", "-o", "x.fits"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: cam.toml: the camera model of 4096 x 4096 pixels needs about ") && stderr.ends_with("more than the memory budget of 256.0 MiB (--max-memory)\n"), "{stderr}");
    assert_eq!(out.status.code(), Some(1));

    // An EMVA image: 512 x 512 pixels at 4 bytes each (the decoder's buffer and the
    // codes) is 1 MiB.
    std::fs::create_dir(d.join("emva")).unwrap();
    let file = std::fs::File::create(d.join("emva/img0.png")).unwrap();
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), 512, 512);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    encoder.write_header().unwrap().write_image_data(&vec![0u8; 512 * 512 * 2]).unwrap();
    std::fs::write(d.join("emva/set.txt"), "v 3.1\nn 12 512 512\nd 1000.0\ni img0.png\ni img0.png\n").unwrap();
    let out = dncal(&["emva", "emva/set.txt", "--max-memory", "512K"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: emva/set.txt: line 4: ") && stderr.ends_with("img0.png: the image's pixels needs about 1.0 MiB, more than the memory budget of 512.0 KiB (--max-memory)\n"), "{stderr}");
    assert_eq!(out.status.code(), Some(1));

    // A budget that is not a size is a usage error (exit 2), naming the flag.
    let out = dncal(&["--max-memory", "lots", "lut", "inspect", "x.fits"], d);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("invalid value 'lots' for '--max-memory <SIZE>'"));
    // Nothing was written by any refusal (lin.fits, cam.toml and emva/ are the test's).
    let mut after = listing(d);
    after.retain(|p| !["lin.fits", "cam.toml", "emva", "wide.fits"].iter().any(|n| p.ends_with(n)));
    assert_eq!(after, before);
}

/// Issue 43's panic and its nonsense results: a valid set whose primary cube reads near
/// -9.3e18 (`BZERO = -9.3e18` on a set without checksums) panicked in the color map of
/// `linearity -o`; an all-zero device image with a valid CRC gave `kcor-model --lut`
/// "infx less" and passed `lut inspect`. Now one line naming the file and what is wrong,
/// exit 1, nothing written.
#[test]
fn values_no_camera_can_give_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(dncal(&["simulate", "linearity", "--levels", "12", "--frames", "4", "--roi", "16x16+0+0", "-o", "lin.fits"], d).status.success());
    let mut bytes = std::fs::read(d.join("lin.fits")).unwrap();
    // In the primary header: CHECKSUM becomes BZERO, DATASUM a blank card.
    let (checksum, _) = card(&bytes, 0, "CHECKSUM");
    bytes[checksum..checksum + 80].copy_from_slice(format!("{:<80}", format!("BZERO   = {:>20}", "-9.3E18")).as_bytes());
    let (datasum, _) = card(&bytes, 0, "DATASUM");
    bytes[datasum..datasum + 80].copy_from_slice(&[b' '; 80]);
    std::fs::write(d.join("bzero.fits"), &bytes).unwrap();
    for args in [&["linearity", "bzero.fits", "-o", "out"][..], &["diagnose", "bzero.fits", "-o", "out"]] {
        let out = dncal(args, d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.starts_with("dncal: error: bzero.fits: mean -9.3") && stderr.contains("is no mean of 12-bit codes") && stderr.lines().count() == 1, "{args:?}: {stderr}");
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(!d.join("out").exists());
    }
    let zero = dncal_host::formats::lut::image::encode(&vec![vec![0u32; 4096]; 4], std::path::Path::new("zero")).unwrap();
    std::fs::write(d.join("zero.bin"), zero).unwrap();
    let flat = "zero.bin: ADC 0's table holds 0 at every code: a LUT maps each code to its cumulative width and must rise (a constant table would read every code as one value)";
    assert_error(&dncal(&["lut", "inspect", "zero.bin"], d), flat);
    assert_error(&dncal(&["kcor-model", "--lut", "zero.bin", "--steps", "8"], d), flat);
}

/// Issue 56: a linearity set whose `NADC` exceeds its columns (65, 1000 or 2e9 on 16)
/// was analysed as one ADC per column, its numbers those of the valid set. `linearity`
/// and `diagnose` refuse it on one line naming the file and both numbers, exit 1, nothing
/// written; the same file with `NADC = 16` is analysed. `simulate linearity` refuses a
/// ROI narrower than the camera's ADCs before simulating it.
#[test]
fn more_adcs_than_columns_are_refused_naming_both_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(dncal(&["simulate", "linearity", "--levels", "12", "--frames", "4", "--roi", "16x16+0+0", "-o", "lin.fits"], d).status.success());
    let mut bytes = std::fs::read(d.join("lin.fits")).unwrap();
    // The primary header's checksums blanked (they would no longer hold), NADC patched.
    for key in ["CHECKSUM", "DATASUM"] {
        let (at, _) = card(&bytes, 0, key);
        bytes[at..at + 80].copy_from_slice(&[b' '; 80]);
    }
    let (nadc, four) = card(&bytes, 0, "NADC");
    assert_eq!(four, 4);
    for n in [16i64, 65, 1000, 2_000_000_000] {
        bytes[nadc + 10..nadc + 30].copy_from_slice(format!("{n:>20}").as_bytes());
        std::fs::write(d.join(format!("nadc{n}.fits")), &bytes).unwrap();
    }
    assert!(dncal(&["linearity", "nadc16.fits"], d).status.success());
    assert!(dncal(&["diagnose", "nadc16.fits"], d).status.success());
    for n in [65, 1000, 2_000_000_000] {
        let line = format!("nadc{n}.fits: NADC = {n} but the frames have 16 columns; column c is read by ADC c mod NADC, so at most 16 ADCs");
        for args in [&["linearity", &format!("nadc{n}.fits"), "-o", "out"][..], &["diagnose", &format!("nadc{n}.fits"), "-o", "out"]] {
            assert_error(&dncal(args, d), &line);
        }
        assert!(!d.join("out").exists());
    }
    let line = "simulate linearity arguments: ROI 3x8 has 3 columns for the camera's 4 ADCs; a linearity set's column c is read by ADC c mod NADC, so it needs at least 4 columns";
    assert_error(&dncal(&["simulate", "linearity", "--roi", "3x8+0+0", "--levels", "3", "--frames", "2", "-o", "narrow.fits"], d), line);
    assert!(!d.join("narrow.fits").exists());
    // A set records ADCMAP = 'COLMOD': from column 5 of a 4-ADC camera its column 0 would
    // be ADC 1's, and every column credited to the wrong ADC.
    let line = "simulate linearity arguments: ROI 16x8 at (5, 0) starts at column 5, which ADC 1 reads; a linearity set's column c is read by ADC c mod NADC, so the ROI must start at a multiple of the camera's 4 ADCs (4 or 8)";
    assert_error(&dncal(&["simulate", "linearity", "--roi", "16x8+5+0", "--levels", "3", "--frames", "2", "-o", "shifted.fits"], d), line);
    assert!(!d.join("shifted.fits").exists());
    assert!(dncal(&["simulate", "linearity", "--roi", "16x8+4+0", "--levels", "3", "--frames", "2", "-o", "aligned.fits"], d).status.success());
    // A camera whose ADCs outnumber its columns has ADCs that read no pixel.
    std::fs::write(d.join("few.toml"), "width = 3\nheight = 8\nn_adc = 4\n").unwrap();
    let out = dncal(&["simulate", "histograms", "--config", "few.toml", "-o", "few.fits"], d);
    assert_clean_failure(&out, "few.toml", "n_adc = 4 ADCs on width = 3 columns");
    assert!(!d.join("few.fits").exists());
}

/// Issue 56: `kind = "ideal"` took any other key and ignored it (serde reads an
/// internally tagged unit variant without its table), while the same key under `sar` or
/// `pipelined` was refused. `simulate` and `stream` refuse it on one line naming the file,
/// the line and the field, exit 1; the config without it runs. (Every table of the
/// model: `config::tests::an_unknown_field_in_any_table_is_refused_naming_it`.)
#[test]
fn an_unknown_field_under_an_ideal_adc_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let camera = "width = 64\nheight = 16\n";
    let ideal = "[[adc.architecture]]\nkind = \"ideal\"\n";
    std::fs::write(d.join("ok.toml"), format!("{camera}{}", ideal.repeat(4))).unwrap();
    assert!(dncal(&["stream", "--config", "ok.toml", "--frames", "1"], d).status.success());
    for (name, extra) in [("weights.toml", "weight_error_lsb = [1.0]"), ("foo.toml", "foo = 1")] {
        std::fs::write(d.join(name), format!("{camera}{ideal}{ideal}{ideal}{extra}\n{ideal}")).unwrap();
        let field = extra.split(' ').next().unwrap();
        for args in [&["simulate", "histograms", "--config", name, "-o", "h.fits"][..], &["simulate", "linearity", "--config", name, "--roi", "16x8+0+0", "-o", "l.fits"], &["stream", "--config", name, "--frames", "1"]] {
            let out = dncal(args, d);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(stderr.starts_with(&format!("dncal: error: {name}: line ")) && stderr.contains(&format!("unknown field `{field}`")), "{args:?}: {stderr}");
            assert_eq!((stderr.lines().count(), out.status.code()), (1, Some(1)), "{args:?}: {stderr}");
        }
        assert!(!d.join("h.fits").exists() && !d.join("l.fits").exists());
    }
}

/// `dncal args` in `dir` under `ulimit -v kib` (the address-space limit, `RLIMIT_AS`).
#[cfg(unix)]
fn dncal_under_ulimit(kib: u64, args: &[&str], dir: &std::path::Path) -> std::process::Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {kib} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_dncal"))
        .args(args)
        .current_dir(dir)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("sh runs")
}

/// Issue 43: the default budget follows the limits the process really has. Under `ulimit
/// -v 4000000`, a 1.2 MB gzip histogram set declaring 1.2e9 counts aborted (`memory
/// allocation of 9600000000 bytes failed`, exit 134): the budget was 3/4 of the machine's
/// memory, and the declaration was allocated before the inflated size was known. Now the
/// declaration is held to the size the file inflates to, and under `ulimit -v 400000` a
/// gzip file inflating to 400 MiB, which the machine's budget lets through, is refused
/// by a budget under the limit.
#[cfg(unix)]
#[test]
fn the_memory_budget_follows_the_process_limits() {
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gzip = |path: &str, cards: &[&str], zeros: usize| {
        let mut header: Vec<u8> = cards.iter().flat_map(|c| format!("{c:<80}").into_bytes()).collect();
        header.resize(2880, b' ');
        let mut z = flate2::write::GzEncoder::new(std::fs::File::create(d.join(path)).unwrap(), flate2::Compression::fast());
        z.write_all(&header).unwrap();
        let block = vec![0u8; 1 << 20];
        for _ in 0..zeros >> 20 {
            z.write_all(&block).unwrap();
        }
        z.finish().unwrap();
    };
    // 1.2e9 counts: 292,969 ADCs of 4096 codes as 8-byte integers, 9.6 GB declared.
    let histograms = ["SIMPLE  =                    T", "BITPIX  =                   64", "NAXIS   =                    2", "NAXIS1  =                 4096", "NAXIS2  =               292969", "BITDEPTH=                   12", "NADC    =               292969", "ADCMAP  = 'COLMOD'", "END"];
    gzip("declared.fits.gz", &histograms, 1200 << 10);
    for args in [&["lut", "build", "declared.fits.gz", "-o", "cal"][..], &["adc", "--hist", "declared.fits.gz", "-o", "a"], &["diagnose", "declared.fits.gz"]] {
        let out = dncal_under_ulimit(4_000_000, args, d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.starts_with("dncal: error: declared.fits.gz: the primary HDU declares its header, data and heap (PCOUNT) to end at byte 9600013440; the file inflates to ") && stderr.ends_with("bytes (truncated?)\n"), "{args:?}: {stderr}");
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    }
    // 400 MiB of zeros behind a plain header, which the machine's budget (3/4 of its
    // memory) lets through: refused by the budget under the limit, 3/4 of what the limit
    // leaves the process.
    gzip("large.fits.gz", &["SIMPLE  =                    T", "BITPIX  =                    8", "NAXIS   =                    0", "END"], 400 << 20);
    let out = dncal_under_ulimit(400_000, &["lut", "inspect", "large.fits.gz"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    // (Refused on the size the gzip trailer declares, before any inflating.)
    let budget = stderr.strip_prefix("dncal: error: large.fits.gz: decompressing it (the size its header declares) needs about 400.0 MiB, more than the memory budget of ").and_then(|r| r.strip_suffix(" MiB (--max-memory)\n"));
    let mib: f64 = budget.and_then(|b| b.parse().ok()).unwrap_or_else(|| panic!("{stderr}"));
    assert!(mib > 0.0 && mib <= 400_000.0 / 1024.0 * 0.75, "budget {mib} MiB under a limit of 390.6 MiB");
    assert_eq!(out.status.code(), Some(1));
    assert!(!d.join("cal.fits").exists() && !d.join("a").exists());
}

/// Issue 43: a header value with terminal escapes (an `ADCMAP` that would set the
/// terminal's title, ring its bell and feed a page) is quoted in the message escaped.
#[test]
fn bytes_from_files_are_printed_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    let mut bytes = std::fs::read(d.join("h.fits")).unwrap();
    for key in ["CHECKSUM", "DATASUM"] {
        if let Some(at) = (0..2880 * 4).step_by(80).find(|&i| bytes[i..i + 8] == *format!("{key:<8}").as_bytes()) {
            bytes[at..at + 80].copy_from_slice(&[b' '; 80]);
        }
    }
    let (at, _) = card(&bytes, 0, "ADCMAP");
    bytes[at..at + 80].copy_from_slice(format!("{:<80}", "ADCMAP  = '\u{1b}]0;owned\u{7}'").as_bytes());
    std::fs::write(d.join("esc.fits"), &bytes).unwrap();
    let out = dncal(&["lut", "build", "esc.fits", "-o", "cal"], d);
    assert_error(&out, "esc.fits: ADCMAP = '\\x1b]0;owned\\x07'; only 'COLMOD' (column c read by ADC c mod NADC) is defined");
}

/// Issue 43: an EMVA descriptor with too few levels is refused from the descriptor, before
/// any image is decoded (two levels of 16384 x 16384 images were decoded, 31-65 s, before
/// the refusal). Here each image is a PNG header of 16384 x 16384 16-bit pixels and no
/// data (the descriptor's check of the headers takes it): decoded, it would be the error.
#[test]
fn too_few_emva_levels_are_refused_before_any_image_is_decoded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut crc = flate2::Crc::new();
        crc.update(kind);
        crc.update(data);
        [&(data.len() as u32).to_be_bytes()[..], kind, data, &crc.sum().to_be_bytes()].concat()
    };
    let ihdr = [&16384u32.to_be_bytes()[..], &16384u32.to_be_bytes(), &[16, 0, 0, 0, 0]].concat();
    // One IDAT of no pixels: the header reads, the pixels are not there.
    let idat = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast()).finish().unwrap();
    let png = [&b"\x89PNG\r\n\x1a\n"[..], &chunk(b"IHDR", &ihdr), &chunk(b"IDAT", &idat), &chunk(b"IEND", &[])].concat();
    std::fs::write(d.join("junk.png"), png).unwrap();
    std::fs::write(d.join("set.txt"), "v 3.0\nn 12 16384 16384\nb 40000.0 120.0\ni junk.png\ni junk.png\nb 40000.0 240.0\ni junk.png\ni junk.png\nd 40000.0\ni junk.png\ni junk.png\n").unwrap();
    let out = dncal(&["emva", "set.txt"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: set.txt: 2 illuminated two-frame levels: at least 6 are needed") && stderr.lines().count() == 1, "{stderr}");
    assert_eq!(out.status.code(), Some(1));
}
