//! Double-buffered LUT banks: one active, one staging.
//!
//! A new calibration is uploaded into the staging bank while the active bank keeps
//! correcting frames. The staging bank becomes activatable only after its whole image
//! has been received and validated ([`crate::image`]); the swap itself is an index flip
//! that the [`Corrector`](crate::Corrector) performs only between frames, so no frame
//! is ever corrected by two calibrations. A corrupted, truncated or half-uploaded image
//! leaves the active bank untouched and the staging bank unusable.
//!
//! The staging bank's contents are a valid [`LutSet`] only in [`StagingState::Valid`];
//! while loading they are a mix of new and old entries, which is why the staging bank is
//! never handed out.

use crate::image::ImageLoader;
use crate::{CoreError, LutSet};

/// What the staging bank holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StagingState {
    /// Nothing activatable.
    Empty,
    /// An upload is in progress.
    Loading,
    /// A validated set, ready to activate.
    Valid,
    /// The last upload failed with this error.
    Failed(CoreError),
}

/// The two banks, the upload state and a pending activation.
pub struct LutBanks<const N: usize, const CODES: usize> {
    banks: [LutSet<N, CODES>; 2],
    active: usize,
    staging: StagingState,
    loader: ImageLoader<N, CODES>,
    pending: bool,
}

impl<const N: usize, const CODES: usize> LutBanks<N, CODES> {
    /// Banks whose active set is `initial`; the staging bank starts empty.
    pub fn new(initial: LutSet<N, CODES>) -> Self {
        LutBanks { banks: [initial.clone(), initial], active: 0, staging: StagingState::Empty, loader: ImageLoader::new(), pending: false }
    }

    /// The set that corrects frames now.
    #[inline]
    pub fn active(&self) -> &LutSet<N, CODES> {
        &self.banks[self.active & 1]
    }

    /// Which bank (0 or 1) is active.
    pub fn active_index(&self) -> usize {
        self.active & 1
    }

    /// The state of the staging bank.
    pub fn staging_state(&self) -> StagingState {
        self.staging
    }

    /// Whether an activation waits for the next frame boundary.
    pub fn activation_pending(&self) -> bool {
        self.pending
    }

    /// Starts receiving an image into the staging bank; cancels a pending activation.
    pub fn begin_upload(&mut self) {
        self.loader = ImageLoader::new();
        self.staging = StagingState::Loading;
        self.pending = false;
    }

    /// The next bytes of the image being uploaded.
    pub fn upload(&mut self, bytes: &[u8]) -> Result<(), CoreError> {
        if self.staging != StagingState::Loading {
            return Err(CoreError::LoaderState);
        }
        let staging = (self.active + 1) & 1;
        let result = self.loader.feed(self.banks[staging].tables_mut(), bytes);
        if let Err(e) = result {
            self.staging = StagingState::Failed(e);
        }
        result
    }

    /// Abandons the open upload (a link lost one of its frames): the staging bank is
    /// failed until the next [`Self::begin_upload`]. Does nothing if no upload is open.
    pub fn abort_upload(&mut self) {
        if self.staging == StagingState::Loading {
            self.staging = StagingState::Failed(CoreError::UploadAborted);
        }
    }

    /// Ends the upload; the staging bank is valid only if this returns `Ok`.
    pub fn finish_upload(&mut self) -> Result<(), CoreError> {
        if self.staging != StagingState::Loading {
            return match self.staging {
                StagingState::Failed(e) => Err(e),
                _ => Err(CoreError::LoaderState),
            };
        }
        let result = self.loader.finish();
        self.staging = match result {
            Ok(()) => StagingState::Valid,
            Err(e) => StagingState::Failed(e),
        };
        result
    }

    /// A whole image in one call: begin, upload, finish.
    pub fn load_image(&mut self, image: &[u8]) -> Result<(), CoreError> {
        self.begin_upload();
        self.upload(image)?;
        self.finish_upload()
    }

    /// Puts an already validated set into the staging bank (host-side use).
    pub fn stage(&mut self, luts: &LutSet<N, CODES>) {
        let staging = (self.active + 1) & 1;
        self.banks[staging].clone_from(luts);
        self.staging = StagingState::Valid;
        self.pending = false;
    }

    /// Marks the valid staging bank for activation at the next frame boundary.
    pub fn request_activation(&mut self) -> Result<(), CoreError> {
        if self.staging != StagingState::Valid {
            return Err(CoreError::StagingNotValid);
        }
        self.pending = true;
        Ok(())
    }

    /// Flips the banks if an activation is pending. A datapath calls this only between
    /// frames (the core's corrector and the FPGA model do). The old active set becomes the
    /// (empty) staging bank.
    pub fn swap_if_pending(&mut self) -> bool {
        if !self.pending {
            return false;
        }
        self.active = (self.active + 1) & 1;
        self.staging = StagingState::Empty;
        self.pending = false;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{encode_image, image_len, Corrector, Geometry};

    #[test]
    fn activation_waits_for_the_frame_boundary() {
        let new = LutSet::<1, 4>::from_bits(&[[10, 20, 30, 40]]).unwrap();
        let mut image = [0u8; image_len::<1, 4>()];
        encode_image(&new, &mut image).unwrap();
        let g = Geometry::new(1, 2, 1, 0).unwrap();
        let mut buf = [0u32; 2];
        let mut banks = LutBanks::new(LutSet::<1, 4>::ideal());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        assert_eq!(c.request_activation(), Err(CoreError::StagingNotValid));
        c.begin_frame(0).unwrap();
        c.accumulate_line(0, &[1]).unwrap();
        c.banks_mut().load_image(&image).unwrap();
        c.request_activation().unwrap();
        c.accumulate_line(1, &[1]).unwrap();
        c.end_frame().unwrap();
        // Both lines of the open frame used the ideal table (1.5 DN = 3072).
        assert_eq!(c.sums().state(0).unwrap(), &[3072, 3072]);
        assert_eq!(c.banks().active(), &new);
        assert_eq!(c.status().lut_swaps, 1);
    }

    #[test]
    fn a_half_upload_leaves_the_active_bank() {
        let new = LutSet::<1, 4>::from_bits(&[[10, 20, 30, 40]]).unwrap();
        let mut image = [0u8; image_len::<1, 4>()];
        encode_image(&new, &mut image).unwrap();
        let mut banks = LutBanks::new(LutSet::<1, 4>::ideal());
        banks.begin_upload();
        banks.upload(&image[..30]).unwrap();
        assert!(banks.finish_upload().is_err());
        assert_eq!(banks.request_activation(), Err(CoreError::StagingNotValid));
        assert_eq!(banks.active(), &LutSet::ideal());
        assert!(!banks.swap_if_pending());
    }

    #[test]
    fn an_aborted_upload_stays_failed_until_begun_again() {
        let mut image = [0u8; image_len::<1, 4>()];
        encode_image(&LutSet::<1, 4>::from_bits(&[[10, 20, 30, 40]]).unwrap(), &mut image).unwrap();
        let mut banks = LutBanks::new(LutSet::<1, 4>::ideal());
        banks.abort_upload();
        assert_eq!(banks.staging_state(), StagingState::Empty, "nothing open, nothing to abort");
        banks.begin_upload();
        banks.upload(&image[..8]).unwrap();
        banks.abort_upload();
        assert_eq!(banks.upload(&image[8..]), Err(CoreError::LoaderState));
        assert_eq!(banks.finish_upload(), Err(CoreError::UploadAborted));
        assert_eq!(banks.request_activation(), Err(CoreError::StagingNotValid));
        banks.begin_upload();
        banks.upload(&image).unwrap();
        banks.finish_upload().unwrap();
    }

    /// The active bank's index: 0 at boot, the other one after each swap.
    #[test]
    fn the_active_index_follows_the_swaps() {
        let mut banks = LutBanks::new(LutSet::<1, 4>::ideal());
        assert_eq!(banks.active_index(), 0);
        for expected in [1, 0, 1] {
            banks.stage(&LutSet::<1, 4>::from_bits(&[[1, 2, 3, 4]]).unwrap());
            banks.request_activation().unwrap();
            assert!(banks.swap_if_pending());
            assert_eq!(banks.active_index(), expected);
        }
        assert!(!banks.swap_if_pending());
    }
}
