//! Fault injection on the SPI bus: test equipment for the link between the core's driver
//! and a datapath (this model, or any other [`SpiDevice`]).
//!
//! [`FaultyBus`] sits between the host and the device and, at transactions chosen by a
//! seeded generator ([`FaultyBus::set_rate`]) or at one chosen by the test
//! ([`FaultyBus::arm`]), injects one of the [`FaultKind`]s. It reports success to the host
//! whatever happened, because a real SPI master hears no acknowledgement: refusals by the
//! device are counted ([`FaultyBus::refusals`]) and not passed on. Bytes the device never
//! drove read as 0xFF (an idle, pulled-up MISO). Every fault is logged ([`Fault`]) so a
//! test can hold the count injected against the count the driver detected.
//!
//! Bit flips come in three shapes, equally often: one bit; two to eight bits of one byte
//! (a burst of at most 8 bits on the wire, which every CRC of 8 bits or more detects);
//! one bit in each of two bytes (a 2-bit error, which the frames' CRC-8 and the image's
//! CRC-32 both detect at their lengths). Faults apply to transactions made of writes and
//! reads only (what the core's driver sends); others pass untouched.

use embedded_hal::spi::{ErrorType, Operation, SpiDevice};

/// The faults the injector knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FaultKind {
    /// Bits flipped in bytes the host writes (MOSI).
    FlipWritten,
    /// Bits flipped in bytes the host reads (MISO).
    FlipRead,
    /// The transaction never reaches the device; the host's read bytes stay idle.
    Drop,
    /// The device receives the transaction twice; the host reads the second answer.
    Duplicate,
    /// Chip-select rises early: the device receives only the first bytes; the host's read
    /// bytes stay idle.
    Truncate,
    /// Chip-select glitches high mid-way: the device receives two transactions, the bytes
    /// before the glitch and those after.
    Glitch,
}

impl FaultKind {
    /// Every kind.
    pub const ALL: [FaultKind; 6] = [FaultKind::FlipWritten, FaultKind::FlipRead, FaultKind::Drop, FaultKind::Duplicate, FaultKind::Truncate, FaultKind::Glitch];

    /// Whether the kind can hit a transaction writing `written` bytes and reading `read`.
    fn applies(self, written: usize, read: usize) -> bool {
        match self {
            FaultKind::FlipWritten => written >= 1,
            FaultKind::FlipRead => read >= 1,
            FaultKind::Drop | FaultKind::Duplicate => true,
            FaultKind::Truncate | FaultKind::Glitch => written >= 2,
        }
    }
}

/// One injected fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fault {
    /// The host's transaction it hit, counted from 0.
    pub transaction: u64,
    /// What was done.
    pub kind: FaultKind,
    /// The first byte the host wrote (the frame's command), 0 if none.
    pub command: u8,
    /// Bits flipped (flips only).
    pub flipped_bits: u32,
    /// Written bytes the device received before the cut (truncations and glitches).
    pub cut_at: usize,
    /// Deliveries to the device (0 dropped, 2 duplicated or split, else 1).
    pub deliveries: u8,
    /// Deliveries the device refused.
    pub refused: u8,
}

/// SplitMix64 (Steele, Lea and Flood 2014): small, seedable, and the same on every
/// platform and version, so a seed names a run. Public so that a test draws its own
/// choices from the same kind of generator.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (0 if `n` is 0), by Lemire's multiply-shift.
    pub fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        ((self.next_u64() >> 11) as f64) < p * (1u64 << 53) as f64
    }
}

/// A transaction's bytes as the injector handles them.
#[derive(Debug, Clone)]
enum Segment {
    Write(Vec<u8>),
    /// The host's read number `.0`, of `.1` bytes.
    Read(usize, usize),
}

/// An [`SpiDevice`] wrapper that injects faults into the transactions it passes on.
pub struct FaultyBus<SPI> {
    inner: SPI,
    rng: SplitMix64,
    rate: f64,
    kinds: Vec<FaultKind>,
    armed: Option<(u64, FaultKind)>,
    transactions: u64,
    log: Vec<Fault>,
    refusals: u64,
    /// Deliveries and refusals of the transaction in hand.
    delivered_now: u8,
    refused_now: u8,
}

impl<SPI: SpiDevice<u8>> FaultyBus<SPI> {
    /// A bus to `inner` that injects nothing until told to; `seed` drives every choice.
    pub fn new(inner: SPI, seed: u64) -> Self {
        FaultyBus { inner, rng: SplitMix64::new(seed), rate: 0.0, kinds: Vec::new(), armed: None, transactions: 0, log: Vec::new(), refusals: 0, delivered_now: 0, refused_now: 0 }
    }

    /// From now on each transaction gets a fault with probability `rate`, of a kind drawn
    /// uniformly from those of `kinds` that can hit it.
    pub fn set_rate(&mut self, rate: f64, kinds: &[FaultKind]) {
        self.rate = rate;
        self.kinds = kinds.to_vec();
    }

    /// One fault of `kind`, in the first transaction it can hit from `after` transactions
    /// from now on (0: the next one). Replaces a fault armed before.
    pub fn arm(&mut self, kind: FaultKind, after: u64) {
        self.armed = Some((self.transactions + after, kind));
    }

    /// Cancels an armed fault; true if it had not fired.
    pub fn disarm(&mut self) -> bool {
        self.armed.take().is_some()
    }

    /// The device.
    pub fn inner(&self) -> &SPI {
        &self.inner
    }

    /// The device, mutably (to stream frames into a model, say).
    pub fn inner_mut(&mut self) -> &mut SPI {
        &mut self.inner
    }

    /// Transactions the host has made.
    pub fn transactions(&self) -> u64 {
        self.transactions
    }

    /// Every fault injected, in order.
    pub fn log(&self) -> &[Fault] {
        &self.log
    }

    /// Faults of `kind` injected.
    pub fn injected(&self, kind: FaultKind) -> usize {
        self.log.iter().filter(|f| f.kind == kind).count()
    }

    /// Deliveries the device refused (and the host never heard of), faulty or not.
    pub fn refusals(&self) -> u64 {
        self.refusals
    }

    fn choose(&mut self, index: u64, written: usize, read: usize) -> Option<FaultKind> {
        if let Some((at, kind)) = self.armed {
            if index >= at && kind.applies(written, read) {
                self.armed = None;
                return Some(kind);
            }
        }
        if self.rate > 0.0 && self.rng.chance(self.rate) {
            let fits: Vec<FaultKind> = self.kinds.iter().copied().filter(|k| k.applies(written, read)).collect();
            if !fits.is_empty() {
                return Some(fits[self.rng.below(fits.len() as u64) as usize]);
            }
        }
        None
    }

    /// Passes `segments` to the device as one transaction; the bytes it returned for each
    /// of the host's reads among them.
    fn deliver(&mut self, segments: &[Segment]) -> Vec<(usize, Vec<u8>)> {
        let mut reads: Vec<(usize, Vec<u8>)> = segments.iter().filter_map(|s| if let Segment::Read(i, n) = s { Some((*i, vec![0xFF; *n])) } else { None }).collect();
        let mut buffers = reads.iter_mut();
        let mut ops: Vec<Operation<'_, u8>> = Vec::with_capacity(segments.len());
        for s in segments {
            match s {
                Segment::Write(bytes) => ops.push(Operation::Write(bytes)),
                Segment::Read(..) => {
                    if let Some((_, buf)) = buffers.next() {
                        ops.push(Operation::Read(buf));
                    }
                }
            }
        }
        self.delivered_now += 1;
        if self.inner.transaction(&mut ops).is_err() {
            self.refusals += 1;
            self.refused_now += 1;
        }
        reads
    }

    /// Flips one to eight bits of `bytes` in one of the three shapes; the bits flipped.
    fn flip(&mut self, bytes: &mut [u8]) -> u32 {
        let n = bytes.len() as u64;
        let shape = if n < 2 { self.rng.below(2) } else { self.rng.below(3) };
        let at = self.rng.below(n) as usize;
        match shape {
            0 => {
                bytes[at] ^= 1 << self.rng.below(8);
                1
            }
            1 => {
                let mut mask = 0u8;
                while mask.count_ones() < 2 {
                    mask = self.rng.next_u64() as u8;
                }
                bytes[at] ^= mask;
                mask.count_ones()
            }
            _ => {
                let other = (at + 1 + self.rng.below(n - 1) as usize) % bytes.len();
                bytes[at] ^= 1 << self.rng.below(8);
                bytes[other] ^= 1 << self.rng.below(8);
                2
            }
        }
    }
}

/// The segments before and after the `cut`-th written byte.
fn split(segments: &[Segment], cut: usize) -> (Vec<Segment>, Vec<Segment>) {
    let (mut before, mut after) = (Vec::new(), Vec::new());
    let mut left = cut;
    for s in segments {
        match s {
            Segment::Write(bytes) if left >= bytes.len() => {
                left -= bytes.len();
                before.push(s.clone());
            }
            Segment::Write(bytes) => {
                if left > 0 {
                    before.push(Segment::Write(bytes[..left].to_vec()));
                }
                after.push(Segment::Write(bytes[left..].to_vec()));
                left = 0;
            }
            Segment::Read(..) if after.is_empty() && left > 0 => before.push(s.clone()),
            Segment::Read(..) => after.push(s.clone()),
        }
    }
    (before, after)
}

/// All the written bytes of `segments`, mutably, in order.
fn written_bytes(segments: &mut [Segment]) -> Vec<&mut u8> {
    segments.iter_mut().flat_map(|s| match s {
        Segment::Write(bytes) => bytes.iter_mut().collect::<Vec<_>>(),
        Segment::Read(..) => Vec::new(),
    }).collect()
}

impl<SPI: SpiDevice<u8>> ErrorType for FaultyBus<SPI> {
    type Error = SPI::Error;
}

impl<SPI: SpiDevice<u8>> SpiDevice<u8> for FaultyBus<SPI> {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), Self::Error> {
        let index = self.transactions;
        self.transactions += 1;
        let plain = ops.iter().all(|op| matches!(op, Operation::Write(_) | Operation::Read(_)));
        if !plain {
            if self.inner.transaction(ops).is_err() {
                self.refusals += 1;
            }
            return Ok(());
        }
        let mut reads = 0;
        let mut segments: Vec<Segment> = ops
            .iter()
            .map(|op| match op {
                Operation::Read(buf) => {
                    reads += 1;
                    Segment::Read(reads - 1, buf.len())
                }
                Operation::Write(bytes) => Segment::Write(bytes.to_vec()),
                _ => Segment::Write(Vec::new()),
            })
            .collect();
        let written: usize = segments.iter().map(|s| if let Segment::Write(b) = s { b.len() } else { 0 }).sum();
        let read: usize = segments.iter().map(|s| if let Segment::Read(_, n) = s { *n } else { 0 }).sum();
        let command = segments.iter().find_map(|s| if let Segment::Write(b) = s { b.first().copied() } else { None }).unwrap_or(0);
        let (mut flipped_bits, mut cut_at) = (0, 0);
        (self.delivered_now, self.refused_now) = (0, 0);
        let kind = self.choose(index, written, read);
        let answers: Vec<(usize, Vec<u8>)> = match kind {
            None => self.deliver(&segments),
            Some(FaultKind::FlipWritten) => {
                let mut bytes: Vec<u8> = written_bytes(&mut segments).into_iter().map(|b| *b).collect();
                flipped_bits = self.flip(&mut bytes);
                for (slot, b) in written_bytes(&mut segments).into_iter().zip(bytes) {
                    *slot = b;
                }
                self.deliver(&segments)
            }
            Some(FaultKind::FlipRead) => {
                let mut answers = self.deliver(&segments);
                let mut bytes: Vec<u8> = answers.iter().flat_map(|(_, b)| b.iter().copied()).collect();
                flipped_bits = self.flip(&mut bytes);
                let mut it = bytes.into_iter();
                for (_, buf) in &mut answers {
                    for (slot, b) in buf.iter_mut().zip(&mut it) {
                        *slot = b;
                    }
                }
                answers
            }
            Some(FaultKind::Drop) => Vec::new(),
            Some(FaultKind::Duplicate) => {
                self.deliver(&segments);
                self.deliver(&segments)
            }
            Some(FaultKind::Truncate) => {
                cut_at = 1 + self.rng.below(written as u64 - 1) as usize;
                let (before, _) = split(&segments, cut_at);
                self.deliver(&before)
            }
            Some(FaultKind::Glitch) => {
                cut_at = 1 + self.rng.below(written as u64 - 1) as usize;
                let (before, after) = split(&segments, cut_at);
                let mut answers = self.deliver(&before);
                answers.extend(self.deliver(&after));
                answers
            }
        };
        if let Some(kind) = kind {
            self.log.push(Fault { transaction: index, kind, command, flipped_bits, cut_at, deliveries: self.delivered_now, refused: self.refused_now });
        }
        let mut read_index = 0;
        for op in ops.iter_mut() {
            if let Operation::Read(buf) = op {
                match answers.iter().find(|(i, _)| *i == read_index) {
                    Some((_, bytes)) => buf.copy_from_slice(bytes),
                    None => buf.fill(0xFF),
                }
                read_index += 1;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::spi::ErrorKind;

    /// A device that records what it receives and answers reads with 0x5A.
    #[derive(Default)]
    struct Recorder(Vec<Vec<u8>>);

    impl ErrorType for Recorder {
        type Error = ErrorKind;
    }

    impl SpiDevice<u8> for Recorder {
        fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
            let mut got = Vec::new();
            for op in ops.iter_mut() {
                match op {
                    Operation::Write(b) => got.extend_from_slice(b),
                    Operation::Read(b) => b.fill(0x5A),
                    _ => {}
                }
            }
            self.0.push(got);
            Ok(())
        }
    }

    fn exchange(bus: &mut FaultyBus<Recorder>) -> [u8; 2] {
        let mut r = [0u8; 2];
        bus.transaction(&mut [Operation::Write(&[1, 2, 3]), Operation::Write(&[4]), Operation::Read(&mut r)]).unwrap();
        r
    }

    #[test]
    fn each_kind_does_what_it_says() {
        let mut bus = FaultyBus::new(Recorder::default(), 1);
        assert_eq!(exchange(&mut bus), [0x5A; 2]);
        bus.arm(FaultKind::Drop, 0);
        assert_eq!(exchange(&mut bus), [0xFF; 2], "a dropped read stays idle");
        bus.arm(FaultKind::Duplicate, 0);
        exchange(&mut bus);
        bus.arm(FaultKind::Truncate, 0);
        assert_eq!(exchange(&mut bus), [0xFF; 2]);
        bus.arm(FaultKind::Glitch, 0);
        assert_eq!(exchange(&mut bus), [0x5A; 2], "the read follows the glitch");
        bus.arm(FaultKind::FlipWritten, 0);
        exchange(&mut bus);
        bus.arm(FaultKind::FlipRead, 0);
        let r = exchange(&mut bus);
        let got = &bus.inner().0;
        assert_eq!(got[0], [1, 2, 3, 4]);
        assert_eq!(got[1], got[2], "duplicated");
        assert_eq!(got[1], [1, 2, 3, 4]);
        let cut = bus.log()[2].cut_at;
        assert_eq!(got[3], [1, 2, 3, 4][..cut], "truncated");
        let glitch = bus.log()[3].cut_at;
        assert_eq!((&got[4][..], &got[5][..]), ([1, 2, 3, 4].split_at(glitch)), "split");
        let flipped: u32 = got[6].iter().zip([1u8, 2, 3, 4]).map(|(a, b)| (a ^ b).count_ones()).sum();
        assert_eq!(flipped, bus.log()[4].flipped_bits);
        let flipped_back: u32 = r.iter().map(|b| (b ^ 0x5A).count_ones()).sum();
        assert_eq!(flipped_back, bus.log()[5].flipped_bits);
        assert_eq!(bus.log().iter().map(|f| f.kind).collect::<Vec<_>>(), FaultKind::ALL[2..].iter().chain(&FaultKind::ALL[..2]).copied().collect::<Vec<_>>());
        assert_eq!(bus.transactions(), 7);
    }

    #[test]
    fn an_armed_fault_waits_for_a_transaction_it_can_hit() {
        let mut bus = FaultyBus::new(Recorder::default(), 2);
        bus.arm(FaultKind::FlipRead, 0);
        bus.transaction(&mut [Operation::Write(&[9])]).unwrap();
        assert!(bus.log().is_empty(), "no read to flip");
        exchange(&mut bus);
        assert_eq!(bus.log().len(), 1);
        assert_eq!(bus.log()[0].transaction, 1);
        assert!(!bus.disarm());
    }

    #[test]
    fn a_rate_injects_about_that_often_and_a_seed_repeats_a_run() {
        let run = |seed| {
            let mut bus = FaultyBus::new(Recorder::default(), seed);
            bus.set_rate(0.1, &FaultKind::ALL);
            for _ in 0..10_000 {
                exchange(&mut bus);
            }
            bus.log().to_vec()
        };
        let a = run(3);
        assert!((900..1100).contains(&a.len()), "{}", a.len());
        assert_eq!(a, run(3));
        assert_ne!(a, run(4));
        for kind in FaultKind::ALL {
            let n = a.iter().filter(|f| f.kind == kind).count();
            assert!((100..250).contains(&n), "{kind:?}: {n}");
        }
    }
}
