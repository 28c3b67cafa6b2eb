//! The FPGA model against the core, configured through the core's SPI driver: for any
//! LUTs, frame size, tap count, memory timing and modulation sequence (with LUT swaps
//! between frames while pixels are still in the pipeline), the sums, frame counts and
//! counters are identical, as long as the FIFO never overflows; an overflow is counted
//! and reported through the register map.

mod common;

use common::{image, luts, weights};
use dncal_core::driver::Datapath;
use dncal_core::{Corrector, Geometry, LutBanks, Mvd1024eLuts};
use dncal_fpga_model::{Config, Fpga};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct Case {
    taps: usize,
    mem_latency: u32,
    h_blank: u32,
    width: u16,
    height: u16,
    states: u8,
    first_column: u16,
    frames: Vec<(u8, Vec<Vec<u16>>, Option<u64>)>,
}

fn case() -> impl Strategy<Value = Case> {
    (1usize..=8, 1u32..40, 0u32..20, 1u16..=37, 1u16..=5, 1u8..=4, 0u16..=9).prop_flat_map(|(taps, mem_latency, h_blank, width, height, states, first_column)| {
        let frame = (0..states, prop::collection::vec(prop::collection::vec(prop_oneof![9 => 0u16..4096, 1 => 4096u16..=u16::MAX], width as usize), height as usize), prop::option::weighted(0.3, any::<u64>()));
        prop::collection::vec(frame, 1..7).prop_map(move |frames| Case { taps, mem_latency, h_blank, width, height, states, first_column, frames })
    })
}

/// The LUT entries of per-code `weights` by the paper's definition, in units of 2^-11 DN:
/// entry k = round-half-even((sum_{j<k} w_j + w_k / 2) 2^11), computed in exact rationals
/// (the weights are on the core's 2^-24 grid: `n_k = 2 sum_{j<k} w_j + w_k` in units of
/// 2^-24 is an integer, the entry is `n_k / 2^14` rounded half to even).
fn entries(weights: &[Vec<f64>]) -> Vec<Vec<u64>> {
    weights
        .iter()
        .map(|t| {
            let bits: Vec<u64> = t.iter().map(|&w| (w * (1u64 << 24) as f64).round() as u64).collect();
            let mut below = 0u64;
            bits.iter()
                .map(|&w| {
                    let n = 2 * below + w;
                    below += w;
                    let (q, r) = (n >> 14, n & ((1 << 14) - 1));
                    if r > (1 << 13) || (r == (1 << 13) && q % 2 == 1) { q + 1 } else { q }
                })
                .collect()
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn the_fpga_model_is_bit_exact_with_the_core(c in case()) {
        let geometry = Geometry::new(c.width, c.height, c.states, c.first_column).unwrap();
        // Enough memory bandwidth for every tap (2 words per pixel) and a FIFO that holds
        // a whole frame: no pixel may be dropped in this test.
        let config = Config { taps: c.taps, fifo_depth: 4096, mem_latency: c.mem_latency, mem_words_per_cycle: 2 * c.taps as u32, h_blank: c.h_blank, v_blank: 3, ..Config::default() };
        let mut dp = Datapath::new(Fpga::new(config, Geometry::new(1, 1, 1, 0).unwrap()).unwrap());
        dp.identify().unwrap();
        dp.configure(geometry).unwrap();
        let first = luts(&weights(1));
        dp.upload_lut_image(&image(&first)).unwrap();

        // The independent reference: the sums by their definition, in u64, one frame at a
        // time (entry of ADC (first column + c) mod 4 at the code, a code above the top
        // read as the top code), clipped to u32 at the end; the core's arithmetic is not
        // used (the model and the core share `lookup` and `saturating_sum`).
        let pixels = c.width as usize * c.height as usize;
        let mut naive = vec![vec![0u64; pixels]; c.states as usize];
        let mut naive_weights = weights(1);
        let mut naive_frames = vec![0u32; c.states as usize];
        let mut banks = LutBanks::new(Mvd1024eLuts::ideal());
        let mut sums = vec![0u32; geometry.sum_len()];
        let mut core = Corrector::new(&mut banks, geometry, &mut sums).unwrap();
        core.banks_mut().stage(&first);
        core.request_activation().unwrap();

        for (state, lines, new_lut) in &c.frames {
            if let Some(seed) = new_lut {
                naive_weights = weights(*seed);
                let l = luts(&weights(*seed));
                dp.upload_lut_image(&image(&l)).unwrap();
                core.banks_mut().stage(&l);
                core.request_activation().unwrap();
            }
            let refs: Vec<&[u16]> = lines.iter().map(|l| l.as_slice()).collect();
            let mut fpga = dp.release();
            fpga.stream_frame(*state, &refs).unwrap();
            dp = Datapath::new(fpga);
            core.begin_frame(*state).unwrap();
            for (row, line) in lines.iter().enumerate() {
                core.accumulate_line(row as u16, line).unwrap();
            }
            core.end_frame().unwrap();
            let table = entries(&naive_weights);
            for (row, line) in lines.iter().enumerate() {
                for (col, &raw) in line.iter().enumerate() {
                    let adc = (c.first_column as usize + col) % 4;
                    naive[*state as usize][row * c.width as usize + col] += table[adc][(raw as usize).min(4095)];
                }
            }
            naive_frames[*state as usize] += 1;
        }
        let counters = dp.counters().unwrap();
        prop_assert_eq!(dp.fifo_overflows().unwrap(), 0);
        let mut fpga = dp.release();
        fpga.drain();
        for s in 0..c.states {
            let want: Vec<u32> = naive[s as usize].iter().map(|&v| v.min(u32::MAX as u64) as u32).collect();
            prop_assert_eq!(fpga.sums(s).unwrap(), &want[..], "state {} against the naive sums", s);
            prop_assert_eq!(fpga.frames(s), naive_frames[s as usize]);
            prop_assert_eq!(fpga.sums(s).unwrap(), core.sums().state(s).unwrap(), "state {}", s);
            prop_assert_eq!(fpga.frames(s), core.sums().frames(s).get());
        }
        let st = core.status();
        prop_assert_eq!(fpga.stats().out_of_range, st.out_of_range_codes);
        prop_assert_eq!(counters.frames, st.frames);
        prop_assert_eq!(counters.lut_swaps, st.lut_swaps);
        prop_assert_eq!(fpga.stats().saturated, st.saturated_additions);
    }
}

#[test]
fn a_starved_memory_overflows_the_fifo_and_says_so() {
    // 8 taps, 2 words per cycle (one pixel per cycle), a 64-pixel FIFO, no blanking:
    // a 1024-pixel line arrives 8 times faster than it drains.
    let config = Config { taps: 8, fifo_depth: 64, mem_latency: 10, mem_words_per_cycle: 2, h_blank: 0, v_blank: 0, ..Config::default() };
    let geometry = Geometry::new(1024, 2, 1, 0).unwrap();
    let mut dp = Datapath::new(Fpga::new(config, geometry).unwrap());
    let line = vec![100u16; 1024];
    let mut fpga = dp.release();
    fpga.stream_frame(0, &[&line, &line]).unwrap();
    fpga.drain();
    dp = Datapath::new(fpga);
    let dropped = dp.fifo_overflows().unwrap();
    let fpga = dp.release();
    // 256 beats of 8 pixels, 1 pixel out per cycle from the second: the FIFO holds
    // 8 + 7k after beat k, full (64) after beat 8; from beat 9 on each beat gets one pixel
    // in and drops 7. Accepted 9 x 8 + 247 = 319, dropped 2048 - 319.
    assert_eq!(dropped, 1729);
    assert_eq!(u64::from(dropped) + fpga.stats().pixels, 2048, "every pixel is either summed or counted as dropped");
    let summed = fpga.sums(0).unwrap().iter().filter(|&&s| s != 0).count() as u64;
    assert_eq!(summed, fpga.stats().pixels, "exactly the accepted pixels have sums");
    assert_eq!(fpga.stats().fifo_high_water, 64);
    assert_eq!(fpga.stats().rmw_hazards, 0, "two 1024-pixel lines never revisit a sum");
}

#[test]
fn a_frame_shorter_than_the_memory_latency_shows_hazards() {
    // A 2-pixel frame, no blanking, 50 cycles of latency: the second frame's pixels are
    // issued while the first frame's writes to the same sums are in flight.
    let config = Config { taps: 2, fifo_depth: 16, mem_latency: 50, mem_words_per_cycle: 4, h_blank: 0, v_blank: 0, ..Config::default() };
    let mut fpga = Fpga::new(config.clone(), Geometry::new(2, 1, 1, 0).unwrap()).unwrap();
    let line = [5u16, 6];
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.drain();
    // Each of the second frame's two pixels reads its sum a few cycles after the first
    // frame's write to it was issued, 50 cycles before that write lands: one hazard per
    // pixel of every frame after the first (the first frame's two sums are distinct).
    assert_eq!(fpga.stats().rmw_hazards, 2);
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.drain();
    assert_eq!(fpga.stats().rmw_hazards, 2, "a frame after a drain finds every write landed");
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.drain();
    assert_eq!(fpga.stats().rmw_hazards, 4);
    // With a 1-cycle memory every write lands before the next frame's read.
    let quick = Config { mem_latency: 1, ..config };
    let mut fpga = Fpga::new(quick, Geometry::new(2, 1, 1, 0).unwrap()).unwrap();
    for _ in 0..3 {
        fpga.stream_frame(0, &[&line]).unwrap();
    }
    fpga.drain();
    assert_eq!(fpga.stats().rmw_hazards, 0);
}

#[test]
fn a_bad_or_partial_upload_never_reaches_the_active_tables() {
    use dncal_core::regs::{control, frame_crc, lut_header, write_frame, Reg, CMD_WRITE_REG};
    use dncal_core::CoreError;
    use embedded_hal::spi::{Operation, SpiDevice};
    let geometry = Geometry::new(16, 2, 1, 0).unwrap();
    let mut dp = Datapath::new(Fpga::new(Config::default(), geometry).unwrap());
    let good = luts(&weights(7));
    dp.upload_lut_image(&image(&good)).unwrap();
    // A corrupt image (one flipped bit) and a partial one (half the bytes, then commit).
    let mut bad = image(&luts(&weights(8)));
    bad[1000] ^= 0x04;
    assert_eq!(dp.upload_lut_image(&bad).unwrap_err(), CoreError::StagingNotValid);
    let partial = image(&luts(&weights(9)));
    dp.write_reg(Reg::Control, control::LUT_BEGIN).unwrap();
    for (k, chunk) in partial[..partial.len() / 2].chunks(256).enumerate() {
        let header = lut_header(256 * k as u32, chunk.len() as u16);
        dp.device_mut().transaction(&mut [Operation::Write(&header), Operation::Write(chunk)]).unwrap();
    }
    dp.write_reg(Reg::Control, control::LUT_COMMIT).unwrap();
    assert!(!dp.status().unwrap().activation_pending, "a partial image is not activated");
    // Malformed transactions are refused (embedded-hal's `Other`: the bus carried a frame
    // the device does not take), not panics, and change nothing.
    let fpga = dp.device_mut();
    let refused = Err(embedded_hal::spi::ErrorKind::Other);
    assert_eq!(fpga.transaction(&mut []), refused);
    assert_eq!(fpga.transaction(&mut [Operation::Write(&[0x7F])]), refused);
    let mut unknown_register = [CMD_WRITE_REG, 0x99, 0, 0, 0, 0, 0];
    unknown_register[6] = frame_crc(&unknown_register[..6]);
    assert_eq!(fpga.transaction(&mut [Operation::Write(&unknown_register)]), refused);
    assert_eq!(fpga.transaction(&mut [Operation::Write(&lut_header(0, 0xFFFF)), Operation::Write(&[0; 4])]), refused);
    // A refused frame holds writes until the next read: a good write is refused too and
    // the width stays; a read ends the hold, and the same write then takes effect.
    assert_eq!(fpga.transaction(&mut [Operation::Write(&write_frame(Reg::Width, 8))]), refused);
    assert_eq!(fpga.geometry().width(), 16);
    assert_eq!(fpga.transaction(&mut [Operation::Write(&dncal_core::regs::read_request(Reg::Id)), Operation::Read(&mut [0; 7])]), Ok(()));
    assert_eq!(fpga.transaction(&mut [Operation::Write(&write_frame(Reg::Width, 8))]), Ok(()));
    assert_eq!(fpga.geometry().width(), 8);
    assert_eq!(fpga.transaction(&mut [Operation::Write(&write_frame(Reg::Width, 16))]), Ok(()));
    // A bad value: refused, the register kept (no hold: the next write applies).
    assert_eq!(fpga.transaction(&mut [Operation::Write(&write_frame(Reg::Width, 0))]), refused, "a zero width is refused");
    assert_eq!(fpga.geometry().width(), 16);
    // Frames are corrected with the good tables only.
    let line: Vec<u16> = (0..16).map(|c| 100 * c as u16).collect();
    fpga.stream_frame(0, &[&line, &line]).unwrap();
    fpga.drain();
    let want: Vec<u32> = line.iter().enumerate().map(|(c, &k)| good.tables()[c % 4][k as usize].to_bits()).collect();
    assert_eq!(&fpga.sums(0).unwrap()[..16], &want[..]);
    assert_eq!(&fpga.sums(0).unwrap()[16..], &want[..]);
}

/// Past 512 frames of the top code the sums clip at 2^32 - 1 and every clipped addition
/// is counted: 600 frames of the ideal top entry, 4095.5 x 2^11, overflow from frame 513
/// on (512 x 8,387,584 = 4,294,443,008 still fits), 88 clipped, against the closed form.
#[test]
fn sums_saturate_past_512_top_code_frames_and_count_it() {
    let config = Config { taps: 1, mem_latency: 3, mem_words_per_cycle: 2, h_blank: 0, v_blank: 0, ..Config::default() };
    let mut fpga = Fpga::new(config, Geometry::new(1, 1, 1, 0).unwrap()).unwrap();
    let line = [4095u16];
    for _ in 0..600 {
        fpga.stream_frame(0, &[&line]).unwrap();
    }
    fpga.drain();
    let entry = (4095u64 << 11) | 1 << 10;
    assert_eq!(u64::from(fpga.sums(0).unwrap()[0]), (600 * entry).min(u64::from(u32::MAX)));
    assert_eq!(fpga.stats().saturated, 600 - (u64::from(u32::MAX) / entry) as u32);
    assert_eq!(fpga.stats().saturated, 88);
}

/// A pixel's latency is the memory's plus one cycle in the FIFO and one in the BRAM;
/// latency 0 is refused.
#[test]
fn latency_is_the_memorys_plus_two_and_zero_is_refused() {
    for l in [1u32, 2, 7, 32] {
        let config = Config { taps: 1, mem_latency: l, mem_words_per_cycle: 2, h_blank: 0, v_blank: 0, ..Config::default() };
        let mut fpga = Fpga::new(config, Geometry::new(1, 1, 1, 0).unwrap()).unwrap();
        fpga.stream_frame(0, &[&[7u16][..]]).unwrap();
        fpga.drain();
        assert_eq!(fpga.stats().max_latency, u64::from(l) + 2, "latency {l}");
    }
    let Err(e) = Fpga::new(Config { mem_latency: 0, ..Config::default() }, Geometry::new(1, 1, 1, 0).unwrap()) else { panic!("a 0-cycle memory was accepted") };
    assert!(matches!(e, dncal_fpga_model::FpgaError::Config("mem_latency", _)), "{e}");
}

/// No burst above the memory's bandwidth after a blanking: on 2 words per cycle (one
/// pixel) at most one read-modify-write is issued per cycle, so no more than the latency
/// (plus the one landing) are ever in flight.
#[test]
fn the_memory_bandwidth_holds_after_a_blanking() {
    let l = 10;
    let config = Config { taps: 8, fifo_depth: 4096, mem_latency: l, mem_words_per_cycle: 2, h_blank: 0, v_blank: 1000, ..Config::default() };
    let mut fpga = Fpga::new(config, Geometry::new(64, 1, 1, 0).unwrap()).unwrap();
    let line = vec![1u16; 64];
    fpga.stream_frame(0, &[&line]).unwrap();
    fpga.drain();
    assert!(fpga.stats().inflight_high_water <= l as usize + 1, "{:?}", fpga.stats());
    assert_eq!(fpga.stats().pixels, 64);
}

/// Register writes cannot make the model allocate what no design has: a geometry beyond
/// the sum memory is refused over SPI and the old one kept (it aborted the process
/// asking for 137 GB).
#[test]
fn a_geometry_beyond_the_sum_memory_is_refused() {
    use dncal_core::regs::{write_frame, Reg};
    use embedded_hal::spi::{Operation, SpiDevice};
    let mut fpga = Fpga::new(Config::default(), Geometry::new(16, 2, 1, 0).unwrap()).unwrap();
    let write = |fpga: &mut Fpga, reg: Reg, v: u32| fpga.transaction(&mut [Operation::Write(&write_frame(reg, v))]);
    assert!(write(&mut fpga, Reg::States, 8).is_ok());
    assert!(write(&mut fpga, Reg::Width, 65535).is_ok(), "8 x 65535 x 2 words fit");
    assert_eq!(write(&mut fpga, Reg::Height, 65535), Err(embedded_hal::spi::ErrorKind::Other));
    assert_eq!(fpga.geometry(), Geometry::new(65535, 2, 8, 0).unwrap());
    assert_eq!(fpga.sums(0).unwrap().len(), 65535 * 2);
}

/// Hardware has two LUT banks: an upload begun while pixels of the previous tables are
/// still queued overwrites the bank they need, and is counted.
#[test]
fn an_upload_over_queued_old_pixels_is_counted() {
    use dncal_core::regs::{control, Reg};
    // A slow memory (one pixel per cycle) behind 8 taps: a 64-pixel line leaves pixels
    // queued when the frame ends.
    let config = Config { taps: 8, fifo_depth: 4096, mem_latency: 4, mem_words_per_cycle: 2, h_blank: 0, v_blank: 0, ..Config::default() };
    let mut dp = Datapath::new(Fpga::new(config, Geometry::new(64, 1, 1, 0).unwrap()).unwrap());
    let line = vec![9u16; 64];
    let mut fpga = dp.release();
    fpga.stream_frame(0, &[&line]).unwrap();
    dp = Datapath::new(fpga);
    // An upload and a swap now, with pixels queued, then another upload begun.
    dp.upload_lut_image(&image(&luts(&weights(3)))).unwrap();
    let mut fpga = dp.release();
    assert_eq!(fpga.stats().lut_swaps, 1);
    // That upload overwrote the staging bank, which no queued pixel used.
    assert_eq!(fpga.stats().lut_overwrite_hazards, 0, "{:?}", fpga.stats());
    fpga.write_register(Reg::Control, control::LUT_BEGIN).unwrap();
    assert_eq!(fpga.stats().lut_overwrite_hazards, 1);
    // Once drained, an upload is safe; and every pixel of the frame was looked up in the
    // tables it entered with (the ideal ones: code 9 is the centre of its bin, 9.5 DN,
    // 9.5 x 2^11), though the swap came while 57 of them were queued.
    fpga.drain();
    assert!(fpga.sums(0).unwrap().iter().all(|&s| s == 19 << 10), "{:?}", fpga.sums(0));
    fpga.write_register(Reg::Control, control::LUT_BEGIN).unwrap();
    assert_eq!(fpga.stats().lut_overwrite_hazards, 1);
}
