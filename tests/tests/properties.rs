//! Property tests of the core's invariants, each against an independent reference.

use dncal_core::stream::StreamHeader;
use dncal_core::{
    encode_image, image_len, Corrector, CoreError, Geometry, HistogramSet, LutBanks, LutSet, Roi, StagingState, Weight, EXACT_FRAMES,
    LUT_ENTRY_LIMIT,
};
use dncal_tests::{lut_bits, naive_histograms, naive_sums};
use proptest::prelude::*;

/// The rounding rule evaluated independently in u128 arithmetic on raw weight bits:
/// entry_k = RNE((2 sum_{j<k} w_j + w_k) / 2^14), ties to even, by explicit remainder
/// comparison.
fn rule_reference(weights: &[u32]) -> Vec<u128> {
    let mut below: u128 = 0;
    weights
        .iter()
        .map(|&w| {
            let n = 2 * below + w as u128;
            below += w as u128;
            let (q, r) = (n / 16384, n % 16384);
            if r * 2 > 16384 || (r * 2 == 16384 && q % 2 == 1) {
                q + 1
            } else {
                q
            }
        })
        .collect()
}

/// CRC-32 (zlib's polynomial, reflected), by the textbook bitwise algorithm.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// The error the LUT-image format (docs: header of 16 bytes, entries little-endian by ADC
/// then code, CRC-32 of all before it) says a reader must give for `flipped`, the valid
/// image `image` of `adcs` tables of `codes` entries with one bit changed: the header's
/// fields in their order, an entry out of range or out of order as the entries arrive
/// (the changed one, or the next one of its table that it now exceeds), else the CRC.
fn expected_rejection(image: &[u8], flipped: &[u8], adcs: usize, codes: usize) -> CoreError {
    let at = image.iter().zip(flipped).position(|(a, b)| a != b).expect("one byte differs");
    let word = |b: &[u8], i: usize| u32::from_le_bytes(b[16 + 4 * i..20 + 4 * i].try_into().unwrap());
    let entries_end = 16 + 4 * adcs * codes;
    match at {
        0..4 => CoreError::ImageMagic,
        4..6 => CoreError::ImageVersion { version: u16::from_le_bytes([flipped[4], flipped[5]]) },
        6..9 => CoreError::ImageLayout { bits: flipped[6], adcs: flipped[7], frac_bits: flipped[8] },
        9..12 => CoreError::ImageReserved,
        12..16 => {
            let count = u32::from_le_bytes(flipped[12..16].try_into().unwrap()) as u64;
            CoreError::ImageLength { expected: (20 + 4 * count).min(u32::MAX as u64) as u32, got: image.len() as u32 }
        }
        _ if at < entries_end => {
            let i = (at - 16) / 4;
            let (adc, code) = (i / codes, i % codes);
            let v = word(flipped, i);
            if v >= 1 << 23 {
                CoreError::EntryOutOfRange { adc: adc as u16, code: code as u16, bits: v }
            } else if code > 0 && v < word(flipped, i - 1) {
                CoreError::NonMonotonic { adc: adc as u16, code: code as u16 }
            } else if code + 1 < codes && word(flipped, i + 1) < v {
                CoreError::NonMonotonic { adc: adc as u16, code: (code + 1) as u16 }
            } else {
                CoreError::ImageCrc { stored: word(image, adcs * codes), computed: crc32(&flipped[..entries_end]) }
            }
        }
        _ => CoreError::ImageCrc { stored: word(flipped, adcs * codes), computed: crc32(&image[..entries_end]) },
    }
}

fn weights_strategy(codes: usize) -> impl Strategy<Value = Vec<u32>> {
    // Raw Weight bits (2^-24 DN units): anything from 0 to ~3 DN wide, ties included.
    proptest::collection::vec(prop_oneof![0u32..(3 << 24), Just(1 << 24), Just(1 << 13), Just(3 << 13)], codes)
}

/// Random monotonic tables of 64 codes for N ADCs (steps below 100 000 units) and
/// `frames` frames of codes 0-79 (some above the top, 63), drawn in that order from `rng`.
fn random_luts_and_frames<const N: usize>(g: Geometry, frames: u32, rng: &mut dncal_host::model::synth::Rng) -> (LutSet<N, 64>, Vec<Vec<u16>>) {
    let tables: [[u32; 64]; N] = core::array::from_fn(|_| {
        let mut acc = 0u32;
        core::array::from_fn(|_| { acc += (rng.next_u64() % 100_000) as u32; acc })
    });
    let luts = LutSet::<N, 64>::from_bits(&tables).unwrap();
    let frame_codes = (0..frames).map(|_| (0..g.pixels()).map(|_| (rng.next_u64() % 80) as u16).collect()).collect();
    (luts, frame_codes)
}

/// Frames of random codes (some above the top, 63) delivered as blocks of whole lines of
/// random sizes (a DMA engine's transfers) through a corrector of N ADCs: the sums and
/// out-of-range counts must be the naive reference's.
fn block_case<const N: usize>(width: u16, height: u16, states: u8, first_column: u16, frames: u32, seed: u64) -> Result<(), TestCaseError> {
    // Frames delivered as blocks of whole lines of random sizes (a DMA engine's
    // transfers): the sums and out-of-range counts are the naive reference's.
    let g = Geometry::new(width, height, states, first_column).unwrap();
    let mut rng = dncal_host::model::synth::Rng::new(seed);
    let (luts, frame_codes) = random_luts_and_frames::<N>(g, frames, &mut rng);
    let mut banks = LutBanks::new(luts.clone());
    let mut sums = vec![0u32; g.sum_len()];
    let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
    let mut out_of_range = 0;
    let w = width as usize;
    for (f, frame) in frame_codes.iter().enumerate() {
        c.begin_frame((f % states as usize) as u8).unwrap();
        let mut row = 0usize;
        while row < height as usize {
            let lines = 1 + (rng.next_u64() as usize) % (height as usize - row);
            out_of_range += c.accumulate_lines(row as u16, &frame[row * w..(row + lines) * w]).unwrap().out_of_range_codes;
            row += lines;
        }
        c.end_frame().unwrap();
    }
    prop_assert_eq!(c.status().incomplete_frames, 0);
    prop_assert_eq!(out_of_range as usize, frame_codes.iter().flatten().filter(|&&x| x > 63).count());
    prop_assert_eq!(c.status().out_of_range_codes as usize, out_of_range as usize);
    let naive = naive_sums(&lut_bits(&luts), g, &frame_codes);
    prop_assert_eq!(sums.iter().map(|&s| s as u64).collect::<Vec<_>>(), naive);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn lut_is_monotonic_bounded_and_follows_the_rounding_rule_for_any_weights(raw in weights_strategy(256)) {
        let weights: Vec<Weight> = raw.iter().map(|&b| Weight::from_bits(b)).collect();
        let reference = rule_reference(&raw);
        match LutSet::<1, 256>::from_weights(&[&weights]) {
            Ok(set) => {
                let bits = &lut_bits(&set)[0];
                prop_assert!(bits.windows(2).all(|p| p[0] <= p[1]));
                prop_assert!(bits.iter().all(|&b| b < LUT_ENTRY_LIMIT));
                prop_assert_eq!(bits.iter().map(|&b| b as u128).collect::<Vec<_>>(), reference);
            }
            Err(CoreError::EntryOutOfRange { code: 255, .. }) => {
                prop_assert!(reference[255] >= LUT_ENTRY_LIMIT as u128, "rejected although the top entry fits");
            }
            Err(e) => prop_assert!(false, "unexpected error {e}"),
        }
    }

    #[test]
    fn line_accumulation_equals_a_naive_reference(
        width in 1u16..40,
        height in 1u16..4,
        states in 1u8..5,
        first_column in 0u16..1000,
        frames in 1u32..12,
        seed in any::<u64>(),
    ) {
        let g = Geometry::new(width, height, states, first_column).unwrap();
        let mut rng = dncal_host::model::synth::Rng::new(seed);
        let (luts, frame_codes) = random_luts_and_frames::<3>(g, frames, &mut rng);
        let mut banks = LutBanks::new(luts.clone());
        let mut sums = vec![0u32; g.sum_len()];
        let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
        let mut out_of_range = 0;
        for (f, frame) in frame_codes.iter().enumerate() {
            c.begin_frame((f % states as usize) as u8).unwrap();
            for (row, line) in frame.chunks_exact(width as usize).enumerate() {
                out_of_range += c.accumulate_line(row as u16, line).unwrap().out_of_range_codes;
            }
            c.end_frame().unwrap();
        }
        prop_assert_eq!(out_of_range as usize, frame_codes.iter().flatten().filter(|&&x| x > 63).count());
        let naive = naive_sums(&lut_bits(&luts), g, &frame_codes);
        prop_assert_eq!(sums.iter().map(|&s| s as u64).collect::<Vec<_>>(), naive);
    }

    #[test]
    fn block_accumulation_equals_the_naive_reference_for_any_split_into_blocks(
        width in 1u16..70,
        height in 1u16..9,
        states in 1u8..5,
        first_column in 0u16..1000,
        frames in 1u32..8,
        seed in any::<u64>(),
    ) {
        // Three ADCs (no vector loop: 3 divides no vector's lanes) and four (the camera's:
        // on x86-64 the gather loop, a block of a width that 4 divides taken as one line).
        block_case::<3>(width, height, states, first_column, frames, seed)?;
        block_case::<4>(width, height, states, first_column, frames, seed)?;
    }

    #[test]
    fn four_adcs_sum_as_the_naive_reference_in_both_modes_with_codes_far_above_the_top(
        width in 1u16..40,
        height in 1u16..3,
        first_column in 0u16..1000,
        frames in prop_oneof![1u32..6, (EXACT_FRAMES - 2)..(EXACT_FRAMES + 6)],
        seed in any::<u64>(),
    ) {
        // Four ADCs (the camera's count: codes go through the loop two to a word) and
        // entries near 2^23, so the frames past 512 clip; the codes mix the range, just
        // above the top and the 16-bit extreme, and some lines hold none above the top.
        let g = Geometry::new(width, height, 1, first_column).unwrap();
        let mut rng = dncal_host::model::synth::Rng::new(seed);
        let tables: [[u32; 64]; 4] = core::array::from_fn(|_| {
            // Every entry above 2^32 / 513: frame 513 clips whatever the codes.
            let mut acc = LUT_ENTRY_LIMIT - 64 * 200;
            core::array::from_fn(|_| { acc += (rng.next_u64() % 200) as u32; acc })
        });
        let luts = LutSet::<4, 64>::from_bits(&tables).unwrap();
        let frame_codes: Vec<Vec<u16>> = (0..frames)
            .map(|_| {
                let wild = rng.next_u64().is_multiple_of(2);
                (0..g.pixels())
                    .map(|_| match rng.next_u64() % 16 {
                        0 if wild => 65535,
                        1 if wild => 64 + (rng.next_u64() % 200) as u16,
                        _ => (rng.next_u64() % 64) as u16,
                    })
                    .collect()
            })
            .collect();
        let mut banks = LutBanks::new(luts.clone());
        let mut sums = vec![0u32; g.sum_len()];
        let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
        let mut out_of_range = 0;
        for frame in &frame_codes {
            c.begin_frame(0).unwrap();
            for (row, line) in frame.chunks_exact(width as usize).enumerate() {
                out_of_range += c.accumulate_line(row as u16, line).unwrap().out_of_range_codes;
            }
            c.end_frame().unwrap();
        }
        let status = c.status();
        drop(c);
        prop_assert_eq!(out_of_range as usize, frame_codes.iter().flatten().filter(|&&x| x > 63).count());
        // Saturating addition of non-negative entries: the u64 sum clipped once at the end,
        // and a clip counted for every addition that starts from or crosses the limit.
        let bits = lut_bits(&luts);
        let mut clips = 0u32;
        let mut running = vec![0u64; g.pixels()];
        for frame in &frame_codes {
            for (i, (&code, r)) in frame.iter().zip(&mut running).enumerate() {
                let entry = bits[(first_column as usize + i % width as usize) % 4][(code as usize).min(63)] as u64;
                clips += (*r + entry > u32::MAX as u64 && entry > 0) as u32;
                *r += entry;
            }
        }
        let naive = naive_sums(&bits, g, &frame_codes);
        prop_assert_eq!(&running, &naive);
        prop_assert_eq!(sums.iter().map(|&s| s as u64).collect::<Vec<_>>(), naive.iter().map(|&s| s.min(u32::MAX as u64)).collect::<Vec<_>>());
        prop_assert_eq!(status.saturated_additions, clips);
        prop_assert!(frames <= EXACT_FRAMES || clips > 0, "entries near 2^23 must clip past 512 frames");
        prop_assert_eq!(status.out_of_range_codes, out_of_range);
    }

    #[test]
    fn sums_never_wrap_in_saturating_mode(extra_frames in 1u32..200, entry in (LUT_ENTRY_LIMIT - 4096)..LUT_ENTRY_LIMIT, low in 0u32..1_000_000) {
        // Two columns: one near the top of the range (must clip), one low (must not).
        let luts = LutSet::<1, 2>::from_bits(&[[low.min(entry), entry]]).unwrap();
        let g = Geometry::new(2, 1, 1, 0).unwrap();
        let mut banks = LutBanks::new(luts);
        let mut sums = vec![0u32; 2];
        let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
        let frames = EXACT_FRAMES + extra_frames;
        let mut previous = [0u32; 2];
        for _ in 0..frames {
            c.begin_frame(0).unwrap();
            c.accumulate_line(0, &[0, 1]).unwrap();
            c.end_frame().unwrap();
            let now = c.sums().state(0).unwrap();
            prop_assert!(now[0] >= previous[0] && now[1] >= previous[1], "a sum decreased: wrapped");
            previous = [now[0], now[1]];
        }
        let exact = [low.min(entry) as u64 * frames as u64, entry as u64 * frames as u64];
        let expected_clips = (1..=frames as u64).filter(|f| f * entry as u64 > u32::MAX as u64).count() as u32
            + (1..=frames as u64).filter(|f| f * low.min(entry) as u64 > u32::MAX as u64).count() as u32;
        prop_assert_eq!(previous[0] as u64, exact[0].min(u32::MAX as u64));
        prop_assert_eq!(previous[1] as u64, exact[1].min(u32::MAX as u64));
        prop_assert_eq!(c.status().saturated_additions, expected_clips);
    }

    #[test]
    fn a_random_bit_flip_of_a_full_size_image_is_rejected(bit in 0usize..image_len::<4, 4096>() * 8, seed in any::<u64>()) {
        let mut rng = dncal_host::model::synth::Rng::new(seed);
        let weights: Vec<Vec<Weight>> = (0..4).map(|_| dncal_host::model::synth::dn_error_weights(&mut rng, 4096)).collect();
        let luts = LutSet::<4, 4096>::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).unwrap();
        let mut image = vec![0u8; image_len::<4, 4096>()];
        encode_image(&luts, &mut image).unwrap();
        let original = image.clone();
        image[bit / 8] ^= 1 << (bit % 8);
        let mut banks = Box::new(LutBanks::new(LutSet::<4, 4096>::ideal()));
        prop_assert_eq!(banks.load_image(&image), Err(expected_rejection(&original, &image, 4, 4096)));
        prop_assert!(matches!(banks.staging_state(), StagingState::Failed(_)));
        prop_assert_eq!(banks.request_activation(), Err(CoreError::StagingNotValid));
        prop_assert_eq!(banks.active(), &LutSet::<4, 4096>::ideal());
    }

    #[test]
    fn histograms_equal_a_naive_count(width in 1u16..30, first_column in 0u16..50, seed in any::<u64>()) {
        let g = Geometry::new(width, 3, 1, first_column).unwrap();
        let mut rng = dncal_host::model::synth::Rng::new(seed);
        let frame: Vec<u16> = (0..g.pixels()).map(|_| (rng.next_u64() % 20) as u16).collect();
        let roi = Roi::new((0, 3), (first_column, first_column + width), g).unwrap();
        let mut h = HistogramSet::<4, 16>::new();
        for (row, line) in frame.chunks_exact(width as usize).enumerate() {
            h.capture_line(&roi, row as u16, first_column, line);
        }
        let got: Vec<u32> = (0..4).flat_map(|a| h.counts(a).unwrap().to_vec()).collect();
        prop_assert_eq!(got, naive_histograms(g, std::slice::from_ref(&frame), 4, 16));
        prop_assert_eq!(h.out_of_range() as usize, frame.iter().filter(|&&c| c > 15).count());
    }

    /// A ROI inside the lines, with some lines wholly in range (the masked path) and some
    /// with codes up to 65535 (the clamped one), against a count written out here.
    #[test]
    fn histograms_of_a_roi_equal_a_naive_count_in_and_out_of_range(
        width in 1u16..40, first_column in 0u16..50, roi_start in 0u16..40, roi_len in 1u16..40,
        wild_rows in proptest::collection::vec(any::<bool>(), 4), seed in any::<u64>(),
    ) {
        let g = Geometry::new(width, 4, 1, first_column).unwrap();
        let start = first_column + roi_start % width;
        let end = (start + roi_len).min(first_column + width);
        let roi = Roi::new((1, 4), (start, end), g).unwrap();
        let mut rng = dncal_host::model::synth::Rng::new(seed);
        let frame: Vec<u16> = (0..g.pixels())
            .map(|i| if wild_rows[i / width as usize] { [rng.next_u64() as u16, 16, 17, 65535][i % 4] } else { (rng.next_u64() % 16) as u16 })
            .collect();
        let mut h = HistogramSet::<4, 16>::new();
        let mut counted = 0;
        for (row, line) in frame.chunks_exact(width as usize).enumerate() {
            counted += h.capture_line(&roi, row as u16, first_column, line);
        }
        let mut expected = vec![0u32; 4 * 16];
        let mut out = 0;
        for row in 1..4usize {
            for column in start..end {
                let code = frame[row * width as usize + (column - first_column) as usize];
                out += (code > 15) as u32;
                expected[(column % 4) as usize * 16 + code.min(15) as usize] += 1;
            }
        }
        let got: Vec<u32> = (0..4).flat_map(|a| h.counts(a).unwrap().to_vec()).collect();
        prop_assert_eq!(counted, 3 * (end - start) as u32);
        prop_assert_eq!(got, expected);
        prop_assert_eq!(h.out_of_range(), out);
    }
}

#[test]
fn every_single_bit_flip_of_an_image_is_rejected() {
    let luts = LutSet::<4, 16>::from_bits(&core::array::from_fn(|a| core::array::from_fn(|k| (a * 1000 + k * 2048 + 17) as u32))).unwrap();
    let mut image = vec![0u8; image_len::<4, 16>()];
    encode_image(&luts, &mut image).unwrap();
    let mut banks = LutBanks::new(LutSet::<4, 16>::ideal());
    banks.load_image(&image).expect("the unflipped image loads");
    for bit in 0..image.len() * 8 {
        let mut flipped = image.clone();
        flipped[bit / 8] ^= 1 << (bit % 8);
        let mut banks = LutBanks::new(LutSet::<4, 16>::ideal());
        assert_eq!(banks.load_image(&flipped), Err(expected_rejection(&image, &flipped, 4, 16)), "bit {bit} flipped");
        assert_eq!(banks.active(), &LutSet::<4, 16>::ideal());
    }
}

#[test]
fn every_truncation_of_an_image_is_rejected_and_leaves_the_active_bank() {
    let luts = LutSet::<2, 8>::from_bits(&[[1, 2, 3, 4, 5, 6, 7, 8], [0, 0, 0, 9, 9, 9, 10, 11]]).unwrap();
    let mut image = vec![0u8; image_len::<2, 8>()];
    encode_image(&luts, &mut image).unwrap();
    for len in 0..image.len() {
        let mut banks = LutBanks::new(LutSet::<2, 8>::ideal());
        banks.begin_upload();
        // Every prefix of a valid image is valid as far as it goes: the end is refused.
        assert_eq!(banks.upload(&image[..len]), Ok(()), "truncated at {len}");
        assert_eq!(banks.finish_upload(), Err(CoreError::ImageLength { expected: image.len() as u32, got: len as u32 }), "truncated at {len}");
        assert_eq!(banks.request_activation(), Err(CoreError::StagingNotValid));
        assert_eq!(banks.active(), &LutSet::<2, 8>::ideal());
    }
}

#[test]
fn five_hundred_twelve_top_code_frames_fit_in_32_bits_on_a_full_line() {
    // The worst case at full width: every entry 2^23 - 1, every code the top code.
    let luts = LutSet::<4, 4096>::from_bits(&[[LUT_ENTRY_LIMIT - 1; 4096]; 4]).unwrap();
    let g = Geometry::new(1024, 1, 1, 0).unwrap();
    let mut banks = Box::new(LutBanks::new(luts));
    let mut sums = vec![0u32; 1024];
    let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
    let line = vec![4095u16; 1024];
    for _ in 0..EXACT_FRAMES {
        c.begin_frame(0).unwrap();
        c.accumulate_line(0, &line).unwrap();
        c.end_frame().unwrap();
    }
    assert_eq!(c.status().saturated_additions, 0);
    assert!(sums.iter().all(|&s| s as u64 == 512 * (LUT_ENTRY_LIMIT as u64 - 1)));
}

#[test]
fn stream_header_rejects_every_single_bit_flip_of_magic_and_version() {
    let h = StreamHeader { geometry: Geometry::new(64, 64, 4, 0).unwrap(), frames: 8, capture_histograms: true }.encode();
    for bit in 0..6 * 8 {
        let mut f = h;
        f[bit / 8] ^= 1 << (bit % 8);
        assert_eq!(StreamHeader::parse(&f), Err(CoreError::StreamHeader), "bit {bit}");
    }
}
