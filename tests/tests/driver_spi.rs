//! The SPI driver against a minimal device written here from the register-map table in
//! `dncal_core::regs` (wire bytes decoded by hand, not by the driver's code), backed by
//! the core's LUT banks.

use dncal_core::driver::Datapath;
use dncal_core::regs::{control, Reg};
use dncal_core::{encode_image, image_len, CoreError, Geometry, LutBanks, LutSet, StagingState};
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};

struct Device {
    id: u32,
    regs: [u32; 0x40],
    banks: LutBanks<1, 4>,
    transactions: Vec<Vec<u8>>,
    fail_bus: bool,
}

impl Device {
    fn new() -> Self {
        Device { id: u32::from_le_bytes(*b"DNCL"), regs: [0; 0x40], banks: LutBanks::new(LutSet::ideal()), transactions: vec![], fail_bus: false }
    }
    fn status(&self) -> u32 {
        let s = self.banks.staging_state();
        (s == StagingState::Valid) as u32
            | (self.banks.activation_pending() as u32) << 1
            | (matches!(s, StagingState::Failed(_)) as u32) << 3
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
        let mut record = vec![];
        let Operation::Write(head) = &ops[0] else { panic!("a transaction starts with the command") };
        let head = head.to_vec();
        record.extend(&head);
        match head[0] {
            0x01 => {
                assert_eq!(head.len(), 6, "WRITE_REG is cmd, addr, u32 LE");
                let value = u32::from_le_bytes(head[2..6].try_into().unwrap());
                self.regs[head[1] as usize / 4] = value;
                if head[1] == 0x04 {
                    if value & 0b10 != 0 {
                        self.banks.begin_upload();
                    }
                    // The swap itself needs the corrector's frame boundary; the device
                    // here only records the pending activation.
                    if value & 0b100 != 0 && self.banks.finish_upload().is_ok() {
                        self.banks.request_activation().unwrap();
                    }
                }
            }
            0x02 => {
                assert_eq!(head.len(), 2);
                let value = match head[1] {
                    0x00 => self.id,
                    0x08 => self.status(),
                    a => self.regs[a as usize / 4],
                };
                let Operation::Read(buf) = &mut ops[1] else { panic!("READ_REG reads 4 bytes") };
                buf.copy_from_slice(&value.to_le_bytes());
            }
            0x03 => {
                let len = u16::from_le_bytes([head[1], head[2]]) as usize;
                let Operation::Write(chunk) = &ops[1] else { panic!("LUT_DATA carries a chunk") };
                assert_eq!(chunk.len(), len);
                assert!(len <= 256);
                record.extend(chunk.iter());
                let _ = self.banks.upload(chunk);
            }
            c => panic!("unknown command {c:#x}"),
        }
        self.transactions.push(record);
        Ok(())
    }
}

#[test]
fn configure_writes_the_documented_bytes() {
    let mut dp = Datapath::new(Device::new());
    dp.identify().unwrap();
    dp.configure(Geometry::new(64, 32, 4, 130).unwrap()).unwrap();
    let dev = dp.release();
    assert_eq!(dev.transactions[0], [0x02, 0x00]);
    assert_eq!(dev.transactions[1..], [
        vec![0x01, 0x0C, 64, 0, 0, 0],
        vec![0x01, 0x10, 32, 0, 0, 0],
        vec![0x01, 0x14, 4, 0, 0, 0],
        vec![0x01, 0x18, 130, 0, 0, 0],
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
    let dev = dp.release();
    assert_eq!(dev.transactions.first().unwrap(), &[0x01, 0x04, control::LUT_BEGIN as u8, 0, 0, 0]);
    let data: Vec<u8> = dev.transactions.iter().filter(|t| t[0] == 0x03).flat_map(|t| t[3..].to_vec()).collect();
    assert_eq!(data, image, "the image arrives whole and in order");
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
    let lens: Vec<usize> = dev.transactions.iter().filter(|t| t[0] == 0x03).map(|t| u16::from_le_bytes([t[1], t[2]]) as usize).collect();
    assert_eq!(lens, [256, 256, 256, 232]);
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
