//! Every LUT representation in one home: our LUT FITS ([`crate::formats::fits::lut`],
//! beside the other FITS codecs), the device image the co-processor loads ([`image`], the
//! core's encoding), and the K-Coronagraph's deployed tables ([`kcor`]). One in-memory
//! form, [`Lut`] (the core's entries and, where the file has them, the code widths they
//! were built from); one [`read`] that tells the formats apart by their bytes and one
//! [`write`] per [`LutFormat`]. `lut inspect`, `lut import`, `lut export`, `lut convert`,
//! `kcor-model --lut` and the fuzz target read and write LUT files through here only.
//!
//! A new format is a variant of [`LutFormat`], its codec in this folder, its arms in
//! [`read`] and [`write`], its section in `docs/formats.md` and its fuzz target.

mod fault;
pub mod image;
pub mod inspect;
pub mod kcor;

use std::fmt;
use std::path::{Path, PathBuf};

use dncal_core::{LutSet, Weight};
use serde::Serialize;

use crate::formats::fits::{read_lut, stage_lut, LutTables};
use crate::formats::outputs::Outputs;
use crate::{HostError, Origin};

pub use fault::LutFault;

/// A LUT file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum LutFormat {
    /// Our LUT FITS: the entries, and the code widths (extension `WEIGHTS`) where known.
    #[serde(rename = "lut-fits")]
    Fits,
    /// The device image the co-processor's staging bank loads (the core's encoding, with
    /// its CRC).
    #[serde(rename = "device-image")]
    DeviceImage,
    /// The K-Coronagraph's four per-ADC tables (`docs/kcor-luts.md`).
    #[serde(rename = "kcor-tables")]
    Kcor,
}

impl LutFormat {
    /// Every format, in the order `lut convert --to` lists them.
    pub const ALL: [LutFormat; 3] = [LutFormat::Fits, LutFormat::DeviceImage, LutFormat::Kcor];
}

impl fmt::Display for LutFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LutFormat::Fits => "lut-fits",
            LutFormat::DeviceImage => "device-image",
            LutFormat::Kcor => "kcor-tables",
        })
    }
}

/// A LUT set as every format holds it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lut {
    /// `tables[adc][code]`: the core's entries, LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`, validated by the core.
    pub tables: Vec<Vec<u32>>,
    /// The per-code weights (code widths, 2^-24 DN) the tables were built from, where the
    /// file carries them (a LUT FITS with `WEIGHTS`, the K-Cor tables); a device image
    /// holds only the entries, which do not determine the widths.
    pub weights: Option<Vec<Vec<Weight>>>,
    /// The K-Cor scaling `B` (last entry `2^B - 1`) of tables imported from K-Cor files.
    pub kcor_bits: Option<u32>,
}

impl Lut {
    /// The core's LUT set from per-ADC `weights`; `source` names the input in errors.
    pub fn from_weights(weights: Vec<Vec<Weight>>, source: impl Into<Origin>) -> Result<Lut, HostError> {
        let (tables, _) = tables_from_weights(&weights, &source.into())?;
        Ok(Lut { tables, weights: Some(weights), kcor_bits: None })
    }

    /// The LUT FITS contents.
    pub fn fits_tables(&self) -> LutTables {
        let weights = self.weights.as_ref().map(|w| w.iter().map(|w| w.iter().map(|x| x.to_bits()).collect()).collect());
        LutTables { frac_bits: crate::infra::dims::lut_frac_bits(self.bit_depth()), tables: self.tables.clone(), weights, kcor_bits: self.kcor_bits }
    }

    /// Bits per code.
    pub fn bit_depth(&self) -> u32 {
        self.tables.first().map_or(0, Vec::len).trailing_zeros()
    }
}

/// Which format `path` holds, from its first bytes: a device image starts with `DNLT`; a
/// file of exactly 4096 little-endian `u32` that is neither FITS nor compressed (the FITS
/// reader opens gzip and the other formats cfitsio inflates) is a K-Cor table; anything
/// else is read as FITS (whose reader says what is wrong with it).
pub fn sniff(path: &Path) -> Result<LutFormat, HostError> {
    use std::io::Read;
    let file = crate::formats::input::open_regular(path)?;
    let len = file.metadata().map_err(|e| HostError::io(path, e))?.len();
    let mut start = Vec::with_capacity(6);
    file.take(6).read_to_end(&mut start).map_err(|e| HostError::io(path, e))?;
    Ok(if start.starts_with(image::MAGIC) {
        LutFormat::DeviceImage
    } else if len == kcor::FILE_BYTES as u64 && !start.starts_with(b"SIMPLE") && !crate::formats::fits::compressed_magic(&start) {
        LutFormat::Kcor
    } else {
        LutFormat::Fits
    })
}

/// Reads the LUT in `path`, of any format ([`sniff`]). A K-Cor table is one of four: the
/// others are found by its name (`..._adc0_...` read as `..._adc{adc}_...`). A device
/// image and K-Cor tables come back as the core loads them; a LUT FITS as the file holds
/// it (the format allows any `u32`): [`validate`] checks it as the core would, and each
/// consumer does so where its own checks do not come first.
pub fn read(path: &Path) -> Result<(LutFormat, Lut), HostError> {
    let format = sniff(path)?;
    let lut = match format {
        LutFormat::DeviceImage => Lut { tables: image::read(path)?, weights: None, kcor_bits: None },
        LutFormat::Fits => read_fits(path)?,
        LutFormat::Kcor => kcor::read_set(&kcor::siblings(path)?)?.1,
    };
    check_rises(&lut, path)?;
    Ok((format, lut))
}

/// Refuses a LUT with a table that does not rise ([`LutFault::FlatTable`]): the formats
/// and the core take it (it is non-decreasing), but every code would read as one value,
/// and an analysis of it reports zeros as a perfect correction.
pub fn check_rises(lut: &Lut, origin: impl Into<Origin>) -> Result<(), HostError> {
    match lut.tables.iter().enumerate().find(|(_, t)| t.first() == t.last()) {
        Some((adc, t)) => Err(HostError::lut(origin, LutFault::FlatTable { adc, entry: t.first().copied().unwrap_or(0) })),
        None => Ok(()),
    }
}

/// A LUT FITS as the file holds it.
pub fn read_fits(path: &Path) -> Result<Lut, HostError> {
    let t = read_lut(path)?;
    let weights = t.weights.map(|w| w.iter().map(|w| w.iter().map(|&b| Weight::from_bits(b)).collect()).collect());
    Ok(Lut { tables: t.tables, weights, kcor_bits: t.kcor_bits })
}

/// Checks `lut`'s tables as the core checks every set it loads (a layout it is built for,
/// every entry below 2^23, none below its predecessor); `path` names the file.
pub fn validate(lut: &Lut, origin: impl Into<Origin>) -> Result<(), HostError> {
    let origin = origin.into();
    let (n, codes) = (lut.tables.len(), lut.tables.first().map_or(0, Vec::len));
    crate::dispatch_lut_dims!(n, codes, origin.clone(), validate_tables(&lut.tables, &origin))
}

/// The core's checks of a LUT set (every entry below 2^23, non-decreasing).
fn validate_tables<const N: usize, const CODES: usize>(tables: &[Vec<u32>], origin: &Origin) -> Result<(), HostError> {
    crate::infra::dims::lut_set::<N, CODES>(tables, origin).map(drop)
}


/// The files [`write`] writes for `-o OUT` in `format`: the LUT FITS `OUT.fits` (OUT
/// itself if it ends in `.fits`), the device image `OUT.bin`, or the four K-Cor tables
/// `OUT_adc0.bin .. OUT_adc3.bin` (OUT with `{adc}` replaced, if it has it). OUT is a
/// file prefix: one naming a directory is refused.
pub fn output_paths(format: LutFormat, out: &Path) -> Result<Vec<PathBuf>, HostError> {
    Ok(match format {
        LutFormat::Fits => vec![LutOutputs::for_prefix(out)?.fits],
        // OUT.bin itself where OUT already ends in .bin.
        LutFormat::DeviceImage if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("bin")) => {
            check_file_prefix(out, "OUT.bin")?;
            vec![out.to_path_buf()]
        }
        LutFormat::DeviceImage => vec![LutOutputs::for_prefix(out)?.image],
        LutFormat::Kcor => {
            let prefix = out.to_string_lossy();
            if !prefix.contains("{adc}") {
                check_file_prefix(out, "OUT_adc0.bin .. OUT_adc3.bin")?;
            }
            (0..4).map(|a| kcor::export_path(&prefix, a)).collect()
        }
    })
}

/// Stages `lut` in `format` at `paths` (from [`output_paths`]) in `files`; `source` names
/// the input in errors. The K-Cor tables need the code widths, at scaling `kcor_bits`
/// (default the LUT's own, else 23), and widths that rebuild the entries (else the file
/// was edited and the two disagree).
pub fn write(files: &mut Outputs, lut: &Lut, format: LutFormat, paths: &[PathBuf], kcor_bits: Option<u32>, source: impl Into<Origin>) -> Result<(), HostError> {
    let source = source.into();
    match format {
        LutFormat::Fits => stage_lut(files, &paths[0], &lut.fits_tables()),
        LutFormat::DeviceImage => files.write_bytes(&paths[0], &image::encode(&lut.tables, source)?),
        LutFormat::Kcor => {
            for (t, path) in kcor::tables_of(lut, kcor_bits, &source)?.iter().zip(paths) {
                files.write_bytes(path, t.to_bytes())?;
            }
            Ok(())
        }
    }
}

/// The core's LUT entries (LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`) and device image for per-ADC `weights`;
/// `source` names the input in errors.
pub fn tables_from_weights(weights: &[Vec<Weight>], source: &Origin) -> Result<(Vec<Vec<u32>>, Vec<u8>), HostError> {
    let codes = weights.first().map_or(0, Vec::len);
    crate::dispatch_lut_dims!(weights.len(), codes, source.clone(), core_tables(weights, source))
}

fn core_tables<const N: usize, const CODES: usize>(weights: &[Vec<Weight>], source: &Origin) -> Result<(Vec<Vec<u32>>, Vec<u8>), HostError> {
    let slices: Vec<&[Weight]> = weights.iter().map(|w| w.as_slice()).collect();
    let slices: &[&[Weight]; N] = slices.as_slice().try_into().map_err(|_| HostError::UnsupportedDims { origin: source.clone(), n_adc: weights.len(), codes: CODES })?;
    let set = Box::new(LutSet::<N, CODES>::from_weights(slices).map_err(|e| HostError::core(format!("{source}: LUT from weights"), e))?);
    let tables = set.tables().iter().map(|t| t.iter().map(|e| e.to_bits()).collect()).collect();
    Ok((tables, image::encode_set(&set)?))
}

/// Where `-o OUT` puts the LUT FITS and the device image: OUT itself if it ends in
/// `.fits` (the image beside it with `.bin`), otherwise `OUT.fits` and `OUT.bin`. OUT
/// is a file prefix ([`check_file_prefix`]), so neither file is hidden in a directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LutOutputs {
    /// The LUT FITS.
    pub fits: PathBuf,
    /// The device image.
    pub image: PathBuf,
}

impl LutOutputs {
    /// The two files, checked ([`Outputs::expect`]), in a new set of outputs.
    pub fn expect(&self) -> Result<Outputs, HostError> {
        let mut files = Outputs::new();
        files.expect([&self.fits, &self.image])?;
        Ok(files)
    }

    /// The two paths for `-o OUT`, or an error naming OUT if it names a directory.
    pub fn for_prefix(out: &Path) -> Result<Self, HostError> {
        check_file_prefix(out, "OUT.fits and OUT.bin")?;
        Ok(if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("fits")) {
            LutOutputs { fits: out.to_path_buf(), image: out.with_extension("bin") }
        } else {
            let s = out.as_os_str().to_string_lossy();
            LutOutputs { fits: PathBuf::from(format!("{s}.fits")), image: PathBuf::from(format!("{s}.bin")) }
        })
    }
}

/// Refuses an `-o` that names a directory (an existing one, or any path ending in `/`)
/// where a file prefix is expected: `DIR/` would become the hidden files `DIR/.fits` and
/// `DIR/.bin`. `writes` says what the prefix becomes, for the message.
pub fn check_file_prefix(out: &Path, writes: &str) -> Result<(), HostError> {
    let text = out.as_os_str().to_string_lossy();
    let trailing_separator = text.ends_with(std::path::is_separator);
    if trailing_separator || out.file_name().is_none() || out.is_dir() {
        let example = if trailing_separator { format!("{text}cal") } else { format!("{text}/cal") };
        return Err(HostError::lut(out, LutFault::OutputIsDirectory { writes: writes.to_string(), example }));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four 12-bit ADCs with a planted width pattern (every width a multiple of 2^-24 DN).
    fn planted() -> Lut {
        let weights: Vec<Vec<Weight>> = (0..4u32)
            .map(|adc| (0..4096u32).map(|k| Weight::from_bits((1 << 24) + ((k * 7919 + adc * 104_729) % 400_001) - 200_000)).collect())
            .collect();
        Lut::from_weights(weights, Path::new("planted")).unwrap()
    }

    fn written(dir: &Path, lut: &Lut, format: LutFormat, name: &str) -> Vec<PathBuf> {
        let paths = output_paths(format, &dir.join(name)).unwrap();
        let mut files = Outputs::new();
        files.expect(&paths).unwrap();
        write(&mut files, lut, format, &paths, None, Path::new("planted")).unwrap();
        files.publish().unwrap();
        paths
    }

    /// Each format read back by the one reader, told apart by its bytes alone (the names
    /// say nothing): the entries come back from every format; the widths from the FITS
    /// and the K-Cor tables (to the K-Cor grid's rounding, which rebuilds the same
    /// entries), not from the device image, which has none.
    #[test]
    fn every_format_reads_back_what_was_written() {
        let dir = tempfile::tempdir().unwrap();
        let lut = planted();
        let fits = written(dir.path(), &lut, LutFormat::Fits, "a");
        // A device image asked for as OUT.bin is OUT.bin, not OUT.bin.bin.
        assert_eq!(output_paths(LutFormat::DeviceImage, &dir.path().join("x.bin")).unwrap(), vec![dir.path().join("x.bin")]);
        assert_eq!(read(&fits[0]).unwrap(), (LutFormat::Fits, lut.clone()));
        let image = written(dir.path(), &lut, LutFormat::DeviceImage, "b");
        assert_eq!(read(&image[0]).unwrap(), (LutFormat::DeviceImage, Lut { weights: None, ..lut.clone() }));
        let kcor_files = written(dir.path(), &lut, LutFormat::Kcor, "c");
        assert_eq!(kcor_files.len(), 4);
        let (format, from_kcor) = read(&kcor_files[2]).unwrap();
        assert_eq!((format, from_kcor.kcor_bits), (LutFormat::Kcor, Some(23)));
        // 2^23 - 1 units over 4095 DN is coarser than the weights' 2^-24 DN: the widths
        // come back rounded, to within one K-Cor unit (4095 / (2^23 - 1) DN) of the sum.
        let unit = 4095.0 / ((1u64 << 23) - 1) as f64;
        for (w, v) in lut.weights.as_ref().unwrap().iter().zip(from_kcor.weights.as_ref().unwrap()) {
            let (mut a, mut b) = (0.0, 0.0);
            for (x, y) in w.iter().zip(v) {
                a += x.to_num::<f64>();
                b += y.to_num::<f64>();
                assert!((a * 4095.0 / w.iter().map(|x| x.to_num::<f64>()).sum::<f64>() - b).abs() <= unit, "{a} {b}");
            }
        }
        // And the K-Cor tables written from what was read are the same bytes.
        let again = written(dir.path(), &from_kcor, LutFormat::Kcor, "d");
        for (x, y) in kcor_files.iter().zip(&again) {
            assert!(std::fs::read(x).unwrap() == std::fs::read(y).unwrap());
        }
    }

    /// What cannot be written is refused before anything is: K-Cor tables from a device
    /// image (no widths), from two ADCs, or from widths that do not rebuild the entries;
    /// a K-Cor table whose name does not say its ADC.
    #[test]
    fn what_a_format_cannot_hold_is_refused_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let lut = planted();
        let paths = output_paths(LutFormat::Kcor, &dir.path().join("x")).unwrap();
        let mut files = Outputs::new();
        let message = |lut: &Lut| write(&mut Outputs::new(), lut, LutFormat::Kcor, &paths, None, Path::new("in.fits")).unwrap_err().to_string();
        assert!(message(&Lut { weights: None, ..lut.clone() }).contains("no WEIGHTS extension"));
        let two = Lut::from_weights(lut.weights.clone().unwrap()[..2].to_vec(), Path::new("two")).unwrap();
        assert!(message(&two).contains("2 ADCs of 4096 codes; K-Cor tables are four ADCs"));
        let mut edited = lut.clone();
        edited.tables[1][100] += 1;
        assert!(message(&edited).contains("ADC 1: the WEIGHTS extension does not rebuild the tables"));
        assert!(write(&mut files, &lut, LutFormat::Kcor, &paths, Some(24), Path::new("in.fits")).unwrap_err().to_string().contains("--bits 24"));
        assert!(paths.iter().all(|p| !p.exists()));
        let table = written(dir.path(), &lut, LutFormat::Kcor, "c")[1].clone();
        let anonymous = dir.path().join("table.bin");
        std::fs::copy(&table, &anonymous).unwrap();
        let e = read(&anonymous).unwrap_err().to_string();
        assert!(e.starts_with(&anonymous.display().to_string()) && e.contains("does not say its ADC"), "{e}");
        assert!(output_paths(LutFormat::Fits, dir.path()).is_err());
    }

    /// Issue 43: an all-zero LUT (a device image with a valid CRC, a FITS without
    /// checksums) is what every format and the core accept, and no LUT: refused on
    /// reading, naming the file and the ADC, so no analysis reports its zeros.
    #[test]
    fn a_table_that_does_not_rise_is_refused_in_every_format() {
        let dir = tempfile::tempdir().unwrap();
        let mut flat = planted();
        flat.tables = vec![vec![0; 4096]; 4];
        let image = dir.path().join("zero.bin");
        std::fs::write(&image, image::encode(&flat.tables, Path::new("zero")).unwrap()).unwrap();
        let e = read(&image).unwrap_err().to_string();
        assert_eq!(e, format!("{}: ADC 0's table holds 0 at every code: a LUT maps each code to its cumulative width and must rise (a constant table would read every code as one value)", image.display()));
        let fits = dir.path().join("zero.fits");
        crate::formats::fits::write_lut(&fits, &Lut { weights: None, ..flat.clone() }.fits_tables()).unwrap();
        assert!(read(&fits).unwrap_err().to_string().contains("ADC 0's table holds 0 at every code"));
        // One constant ADC among rising ones is named.
        let mut one = planted();
        one.tables[2] = vec![5000; 4096];
        let image = dir.path().join("one.bin");
        std::fs::write(&image, image::encode(&one.tables, Path::new("one")).unwrap()).unwrap();
        assert!(read(&image).unwrap_err().to_string().contains("ADC 2's table holds 5000 at every code"));
    }

    /// A file of a K-Cor table's length is one only if it is neither FITS nor compressed
    /// (the FITS reader inflates gzip, compress and zip files); a device image is known by
    /// its magic whatever its length.
    #[test]
    fn the_format_is_told_by_the_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let file = |name: &str, start: &[u8]| {
            let mut bytes = start.to_vec();
            bytes.resize(kcor::FILE_BYTES, 0);
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        assert_eq!(sniff(&file("a_adc0.bin", &[0, 0, 0, 0])).unwrap(), LutFormat::Kcor);
        for (name, start) in [("gz", &[0x1f, 0x8b][..]), ("z", &[0x1f, 0x9d]), ("zip", b"PK\x03\x04"), ("fits", b"SIMPLE  =")] {
            assert_eq!(sniff(&file(name, start)).unwrap(), LutFormat::Fits, "{name}");
        }
        assert_eq!(sniff(&file("img", b"DNLT")).unwrap(), LutFormat::DeviceImage);
    }
}
