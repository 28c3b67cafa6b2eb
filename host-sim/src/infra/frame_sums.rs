//! The core's corrector for a host that owns the LUT banks and the sums and hands it
//! frames one call at a time (the Python package's `Corrector`): the sums live in the
//! core's [`SealedSums`], which only a corrector writes, so a run cut into calls is bit
//! for bit one uninterrupted run, the switch to saturating addition after 512 frames
//! included, at no cost per call. The LUT layout (ADCs, codes) is a compile-time size of
//! the core; [`FrameSums`] hides it behind one type.

use dncal_core::{CoreError, Geometry, LutBanks, SealedSums, Status, Suspended};

use crate::infra::dims::lut_set;
use crate::{HostError, Origin};

/// Per-state sums of LUT-corrected frames, owned (see the module documentation).
pub struct FrameSums {
    engine: Box<dyn Engine>,
}

impl std::fmt::Debug for FrameSums {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameSums").field("geometry", &self.geometry()).field("status", &self.status()).finish()
    }
}

impl FrameSums {
    /// Sums over `geometry` with the LUT set `tables` (`tables[adc][code]`, units of
    /// 2^-11 DN), which the core validates; `origin` names the tables in errors.
    pub fn new(tables: &[Vec<u32>], origin: impl Into<Origin>, geometry: Geometry) -> Result<Self, HostError> {
        let origin = origin.into();
        let (n, codes) = (tables.len(), tables.first().map_or(0, Vec::len));
        let engine = crate::dispatch_lut_dims!(n, codes, origin.clone(), engine(tables, &origin, geometry))?;
        Ok(FrameSums { engine })
    }

    /// Adds frames: `codes` holds `states.len()` whole frames, row-major, one after the
    /// other; frame `i` goes into state `states[i]`. A wrong length or a state out of range
    /// is refused before any frame is added.
    pub fn add_frames(&mut self, codes: &[u16], states: &[u8]) -> Result<(), HostError> {
        let g = self.geometry();
        if states.len().checked_mul(g.pixels()) != Some(codes.len()) {
            let expected = states.len().saturating_mul(g.pixels()).try_into().unwrap_or(u32::MAX);
            let e = CoreError::Length { what: dncal_core::error::Quantity::BlockPixels, expected, got: codes.len().try_into().unwrap_or(u32::MAX) };
            return Err(HostError::core("frames", e));
        }
        if let Some(&state) = states.iter().find(|&&s| s >= g.states()) {
            return Err(HostError::core("frames", CoreError::State { state, states: g.states() }));
        }
        self.engine.add_frames(codes, states).map_err(|e| HostError::core("frames", e))
    }

    /// The sums, state-major, then row, then column (units of 2^-11 DN).
    pub fn sums(&self) -> &[u32] {
        self.engine.sums()
    }

    /// Frames added to each state.
    pub fn frames_per_state(&self) -> Vec<u32> {
        let s = self.engine.suspended();
        (0..s.geometry().states()).map(|state| s.frames(state).get()).collect()
    }

    /// The core's counters (codes above the top, clipped additions, ...).
    pub fn status(&self) -> Status {
        self.engine.suspended().status()
    }

    /// The geometry.
    pub fn geometry(&self) -> Geometry {
        self.engine.suspended().geometry()
    }

    /// Zeroes the sums, frame counts and counters, as after a readout.
    pub fn clear(&mut self) {
        self.engine.clear();
    }
}

/// [`FrameSums`] for one LUT layout.
trait Engine: Send + Sync {
    fn add_frames(&mut self, codes: &[u16], states: &[u8]) -> Result<(), CoreError>;
    fn sums(&self) -> &[u32];
    fn suspended(&self) -> &Suspended;
    fn clear(&mut self);
}

struct Owned<const N: usize, const CODES: usize> {
    banks: Box<LutBanks<N, CODES>>,
    sums: SealedSums<Vec<u32>>,
}

fn engine<const N: usize, const CODES: usize>(tables: &[Vec<u32>], origin: &Origin, geometry: Geometry) -> Result<Box<dyn Engine>, HostError> {
    let set = lut_set::<N, CODES>(tables, origin)?;
    let banks = Box::new(LutBanks::new(*set));
    let sums = SealedSums::new(geometry, vec![0u32; geometry.sum_len()]).map_err(|e| HostError::core(origin.to_string(), e))?;
    Ok(Box::new(Owned { banks, sums }))
}

impl<const N: usize, const CODES: usize> Engine for Owned<N, CODES> {
    fn add_frames(&mut self, codes: &[u16], states: &[u8]) -> Result<(), CoreError> {
        let pixels = self.sums.kept().geometry().pixels();
        self.sums.correct(&mut self.banks, |c| {
            for (frame, &state) in codes.chunks_exact(pixels).zip(states) {
                c.begin_frame(state)?;
                c.accumulate_lines(0, frame)?;
                c.end_frame()?;
            }
            Ok(())
        })?
    }

    fn sums(&self) -> &[u32] {
        self.sums.sums()
    }

    fn suspended(&self) -> &Suspended {
        self.sums.kept()
    }

    fn clear(&mut self) {
        self.sums.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Entry `code * (adc + 1)` for 4 ADCs of 256 codes (units of 2^-11 DN).
    fn tables() -> Vec<Vec<u32>> {
        (0..4u32).map(|a| (0..256u32).map(|c| c * (a + 1)).collect()).collect()
    }

    #[test]
    fn frames_added_in_calls_sum_by_hand() {
        // 3 x 2 pixels from sensor column 1, 2 states; each sum worked out by hand from
        // the table rule: pixel (row, col) of frame f has code 10 f + col + 1, read by ADC
        // (1 + col) mod 4.
        let g = Geometry::new(3, 2, 2, 1).unwrap();
        let mut s = FrameSums::new(&tables(), Origin::Argument("luts"), g).unwrap();
        let frame = |f: u16| -> Vec<u16> { (0..6).map(|i| 10 * f + (i % 3) + 1).collect() };
        s.add_frames(&frame(0), &[0]).unwrap();
        s.add_frames(&[frame(1), frame(2)].concat(), &[1, 0]).unwrap();
        s.add_frames(&[300, 0, 0, 0, 0, 0], &[1]).unwrap();
        let want = |state: usize, i: usize| -> u32 {
            let frames: &[u16] = if state == 0 { &[0, 2] } else { &[1] };
            let adc = (1 + i % 3) as u32 % 4;
            let from_frames: u32 = frames.iter().map(|&f| (10 * f as u32 + (i % 3) as u32 + 1) * (adc + 1)).sum();
            // The code 300 frame: above the top, read as code 255 (pixel 0, ADC 1).
            from_frames + if state == 1 && i == 0 { 255 * 2 } else { 0 }
        };
        for state in 0..2 {
            for i in 0..6 {
                assert_eq!(s.sums()[state * 6 + i], want(state, i), "state {state}, pixel {i}");
            }
        }
        assert_eq!(s.frames_per_state(), vec![2, 2]);
        assert_eq!((s.status().out_of_range_codes, s.status().frames), (1, 4));
        s.clear();
        assert!(s.sums().iter().all(|&x| x == 0));
        assert_eq!((s.frames_per_state(), s.status().frames), (vec![0, 0], 0));
    }

    #[test]
    fn bad_frames_are_refused_before_any_is_added() {
        let g = Geometry::new(2, 2, 2, 0).unwrap();
        let mut s = FrameSums::new(&tables(), Origin::Argument("luts"), g).unwrap();
        let e = s.add_frames(&[1; 7], &[0, 1]).unwrap_err().to_string();
        assert!(e.contains("frames") && e.contains('8') && e.contains('7'), "{e}");
        let e = s.add_frames(&[1; 8], &[0, 2]).unwrap_err().to_string();
        assert!(e.contains("modulation state 2 not below 2"), "{e}");
        assert!(s.sums().iter().all(|&x| x == 0));
        assert_eq!(s.status().frames, 0);
        // Tables the core refuses, and a layout it is not built for.
        let mut bad = tables();
        bad[2][7] = 0;
        let e = FrameSums::new(&bad, Origin::Argument("luts"), g).unwrap_err().to_string();
        assert!(e.starts_with("luts"), "{e}");
        assert!(FrameSums::new(&[vec![0; 3]], Origin::Argument("luts"), g).is_err());
    }
}
