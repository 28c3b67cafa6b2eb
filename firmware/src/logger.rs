//! The defmt global logger: rzCOBS-framed defmt records appended to the host file
//! `defmt.bin` over semihosting. The host decodes it with the firmware's ELF
//! (tests/firmware_qemu.rs). Single core, no interrupts log: a flag guards re-entry.

use core::sync::atomic::{AtomicBool, Ordering};

use crate::host_file::HostFile;

#[defmt::global_logger]
struct Logger;

static TAKEN: AtomicBool = AtomicBool::new(false);
static mut ENCODER: defmt::Encoder = defmt::Encoder::new();
static mut FILE: Option<HostFile> = None;

fn write_out(bytes: &[u8]) {
    // SAFETY: only called between acquire and release, which `TAKEN` makes exclusive.
    let file = unsafe { &mut *core::ptr::addr_of_mut!(FILE) };
    if file.is_none() {
        *file = HostFile::create("defmt.bin").ok();
    }
    if let Some(f) = file.as_mut() {
        // A log that cannot be written is dropped; the run's results do not depend on it.
        let _ = f.write_all(bytes);
    }
}

// SAFETY: acquire/release bracket every use of ENCODER and FILE, and TAKEN refuses nesting.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        if TAKEN.swap(true, Ordering::Acquire) {
            // Re-entrant logging (a log inside a log) cannot happen without interrupts.
            cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
        }
        unsafe { (*core::ptr::addr_of_mut!(ENCODER)).start_frame(write_out) }
    }

    unsafe fn flush() {}

    unsafe fn release() {
        unsafe { (*core::ptr::addr_of_mut!(ENCODER)).end_frame(write_out) };
        TAKEN.store(false, Ordering::Release);
    }

    unsafe fn write(bytes: &[u8]) {
        unsafe { (*core::ptr::addr_of_mut!(ENCODER)).write(bytes, write_out) }
    }
}
