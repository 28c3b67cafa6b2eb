//! The SPI driver against a minimal device written here from the register-map table in
//! `dncal_core::regs` (wire bytes decoded by hand and CRC-8/SMBUS computed bit by bit,
//! not by the core's code), backed by the core's LUT banks.

use dncal_core::driver::{Datapath, LinkStats};
use dncal_core::regs::{control, Reg};
use dncal_core::{encode_image, image_len, CoreError, Geometry, LutBanks, LutSet, StagingState};
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};

/// CRC-8/SMBUS, the textbook way: polynomial x^8 + x^2 + x + 1, initial value 0, MSB first.
fn crc8(bytes: &[u8]) -> u8 {
    let mut crc = 0u8;
    for &b in bytes {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
        }
    }
    crc
}

fn with_crc(bytes: &[u8]) -> Vec<u8> {
    let mut v = bytes.to_vec();
    v.push(crc8(bytes));
    v
}

struct Device {
    id: u32,
    regs: [u32; 0x40],
    banks: LutBanks<1, 4>,
    /// Every transaction's written bytes.
    transactions: Vec<Vec<u8>>,
    fail_bus: bool,
    /// Frames accepted, returned with every read.
    count: u16,
    /// Image bytes of the upload open on the link.
    lut_received: Option<u32>,
}

impl Device {
    fn new() -> Self {
        Device { id: u32::from_le_bytes(*b"DNCL"), regs: [0; 0x40], banks: LutBanks::new(LutSet::ideal()), transactions: vec![], fail_bus: false, count: 0, lut_received: None }
    }
    fn status(&self) -> u32 {
        let s = self.banks.staging_state();
        (s == StagingState::Valid) as u32
            | (self.banks.activation_pending() as u32) << 1
            | (matches!(s, StagingState::Failed(_)) as u32) << 3
            | ((s == StagingState::Loading) as u32) << 4
            | (self.banks.active_index() as u32) << 8
    }
}

impl ErrorType for Device {
    type Error = ErrorKind;
}

impl SpiDevice for Device {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        if self.fail_bus {
            return Err(ErrorKind::Other);
        }
        let mut frame = vec![];
        for op in ops.iter() {
            if let Operation::Write(b) = op {
                frame.extend_from_slice(b);
            }
        }
        self.transactions.push(frame.clone());
        match frame[0] {
            0x01 => {
                assert_eq!(frame.len(), 7, "WRITE_REG is cmd, addr, u32 LE, crc8");
                assert_eq!(frame[6], crc8(&frame[..6]));
                let value = u32::from_le_bytes(frame[2..6].try_into().unwrap());
                self.regs[frame[1] as usize / 4] = value;
                if frame[1] == 0x04 {
                    if value & 0b10 != 0 {
                        self.banks.begin_upload();
                        self.lut_received = Some(0);
                    }
                    if value & 0b1_0100 != 0 {
                        self.lut_received = None;
                        if self.banks.staging_state() == StagingState::Loading {
                            let _ = self.banks.finish_upload();
                        }
                    }
                    // The swap itself needs the corrector's frame boundary; the device
                    // here only records the pending activation.
                    if value & 0b100 != 0 && self.banks.staging_state() == StagingState::Valid {
                        self.banks.request_activation().unwrap();
                    }
                }
            }
            0x02 => {
                assert_eq!(frame.len(), 3);
                assert_eq!(frame[2], crc8(&frame[..2]));
                let value = match frame[1] {
                    0x00 => self.id,
                    0x08 => self.status(),
                    a => self.regs[a as usize / 4],
                };
                self.count = self.count.wrapping_add(1);
                let Operation::Read(buf) = &mut ops[1] else { panic!("READ_REG reads 7 bytes") };
                let mut answer = vec![0x02, frame[1]];
                answer.extend_from_slice(&value.to_le_bytes());
                answer.extend_from_slice(&self.count.to_le_bytes());
                buf.copy_from_slice(&with_crc(&answer)[2..]);
                return Ok(());
            }
            0x03 => {
                let offset = u32::from_le_bytes(frame[1..5].try_into().unwrap());
                let len = u16::from_le_bytes([frame[5], frame[6]]) as usize;
                assert_eq!(frame.len(), 7 + len);
                assert!(len <= 256);
                assert_eq!(self.lut_received, Some(offset), "chunks arrive in order");
                self.lut_received = Some(offset + len as u32);
                let _ = self.banks.upload(&frame[7..]);
            }
            c => panic!("unknown command {c:#x}"),
        }
        self.count = self.count.wrapping_add(1);
        Ok(())
    }
}

#[test]
fn configure_writes_the_documented_bytes() {
    let mut dp = Datapath::new(Device::new());
    dp.identify().unwrap();
    dp.configure(Geometry::new(64, 32, 4, 130).unwrap()).unwrap();
    assert_eq!(dp.link_stats(), LinkStats::default(), "a clean device fails no check");
    let dev = dp.release();
    assert_eq!(dev.transactions[0], [0x02, 0x00, crc8(&[0x02, 0x00])]);
    // Each write, then its read-back.
    assert_eq!(dev.transactions[1..], [
        with_crc(&[0x01, 0x0C, 64, 0, 0, 0]),
        with_crc(&[0x02, 0x0C]),
        with_crc(&[0x01, 0x10, 32, 0, 0, 0]),
        with_crc(&[0x02, 0x10]),
        with_crc(&[0x01, 0x14, 4, 0, 0, 0]),
        with_crc(&[0x02, 0x14]),
        with_crc(&[0x01, 0x18, 130, 0, 0, 0]),
        with_crc(&[0x02, 0x18]),
    ]);
    assert_eq!(dev.regs[Reg::Width as usize / 4], 64);
}

#[test]
fn a_valid_image_uploads_in_chunks_and_a_corrupt_one_is_refused() {
    let luts = LutSet::<1, 4>::from_bits(&[[100, 200, 300, 400]]).unwrap();
    let mut image = vec![0u8; image_len::<1, 4>()];
    encode_image(&luts, &mut image).unwrap();

    let mut dp = Datapath::new(Device::new());
    let status = dp.upload_lut_image(&image).unwrap();
    assert!(status.activation_pending, "commit requests activation");
    assert!(!status.upload_failed);
    assert_eq!(dp.link_stats().detections(), 0);
    let dev = dp.release();
    // A read of STATUS to learn the frame count, then LUT_BEGIN, then its confirmation.
    assert_eq!(dev.transactions[..3], [with_crc(&[0x02, 0x08]), with_crc(&[0x01, 0x04, control::LUT_BEGIN as u8, 0, 0, 0]), with_crc(&[0x02, 0x08])]);
    let data: Vec<u8> = dev.transactions.iter().filter(|t| t[0] == 0x03).flat_map(|t| t[7..].to_vec()).collect();
    assert_eq!(data, image, "the image arrives whole and in order");
    let controls: Vec<u8> = dev.transactions.iter().filter(|t| t[..2] == [0x01, 0x04]).map(|t| t[2]).collect();
    assert_eq!(controls, [control::LUT_BEGIN as u8, control::LUT_END as u8, control::LUT_COMMIT as u8]);
    assert_eq!(dev.banks.staging_state(), StagingState::Valid);

    let mut bad = image.clone();
    bad[20] ^= 0x10;
    let mut dp = Datapath::new(Device::new());
    assert_eq!(dp.upload_lut_image(&bad).unwrap_err(), CoreError::StagingNotValid);
    let dev = dp.release();
    assert_eq!(dev.banks.active(), &LutSet::ideal());
}

#[test]
fn large_images_travel_in_256_byte_chunks() {
    let luts = LutSet::<1, 4>::ideal();
    let mut image = vec![0u8; image_len::<1, 4>()];
    encode_image(&luts, &mut image).unwrap();
    let big: Vec<u8> = image.iter().cycle().take(1000).copied().collect();
    let mut dp = Datapath::new(Device::new());
    let _ = dp.upload_lut_image(&big);
    let dev = dp.release();
    let lens: Vec<usize> = dev.transactions.iter().filter(|t| t[0] == 0x03).map(|t| u16::from_le_bytes([t[5], t[6]]) as usize).collect();
    let offsets: Vec<u32> = dev.transactions.iter().filter(|t| t[0] == 0x03).map(|t| u32::from_le_bytes(t[1..5].try_into().unwrap())).collect();
    assert_eq!(lens, [256, 256, 256, 232]);
    assert_eq!(offsets, [0, 256, 512, 768]);
}

#[test]
fn bus_errors_and_foreign_devices_are_reported() {
    let mut dev = Device::new();
    dev.fail_bus = true;
    assert_eq!(Datapath::new(dev).identify(), Err(CoreError::Bus));
    let mut dev = Device::new();
    dev.id = 0x1234_5678;
    assert_eq!(Datapath::new(dev).identify(), Err(CoreError::DeviceId { id: 0x1234_5678 }));
}
