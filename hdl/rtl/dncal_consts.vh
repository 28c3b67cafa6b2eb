// Generated from the core by fpga-model/tests/rtl_cosim.rs (DNCAL_BLESS=1 cargo test -p dncal-fpga-model --test rtl_cosim); do not edit.
`ifndef DNCAL_CONSTS_VH
`define DNCAL_CONSTS_VH
// LUT entry bits (dncal_core::LUT_ENTRY_BITS)
`define DNCAL_ENTRY_BITS 23
// bits of a code (log2 of the model's CODES)
`define DNCAL_CODE_BITS 12
// ADCs, column c read by ADC c mod ADCS (the model's ADCS)
`define DNCAL_ADCS 4
// modulation states (dncal_core::MAX_STATES)
`define DNCAL_MAX_STATES 8
// frames a state sums exactly (dncal_core::EXACT_FRAMES)
`define DNCAL_EXACT_FRAMES 512
// bits of a sum address (log2 of the model's default sum_words)
`define DNCAL_ADDR_W 26
// the ID register's value (dncal_core::regs::DEVICE_ID)
`define DNCAL_DEVICE_ID 1279479364
// SPI command: write a register
`define DNCAL_CMD_WRITE_REG 1
// SPI command: read a register
`define DNCAL_CMD_READ_REG 2
// SPI command: LUT image bytes
`define DNCAL_CMD_LUT_DATA 3
// largest LUT chunk, bytes
`define DNCAL_MAX_LUT_CHUNK 256
// bytes of a WRITE_REG frame
`define DNCAL_WRITE_FRAME_LEN 7
// bytes of a READ_REG request
`define DNCAL_READ_REQUEST_LEN 3
// bytes clocked back after a READ_REG request
`define DNCAL_READ_RESPONSE_LEN 7
// bytes of a LUT_DATA header
`define DNCAL_LUT_HEADER_LEN 7
// CONTROL: LUT_BEGIN
`define DNCAL_CONTROL_LUT_BEGIN 2
// CONTROL: LUT_COMMIT
`define DNCAL_CONTROL_LUT_COMMIT 4
// CONTROL: CLEAR_SUMS
`define DNCAL_CONTROL_CLEAR_SUMS 8
// CONTROL: LUT_END
`define DNCAL_CONTROL_LUT_END 16
// STATUS: staging valid
`define DNCAL_STATUS_STAGING_VALID 1
// STATUS: activation pending
`define DNCAL_STATUS_ACTIVATION_PENDING 2
// STATUS: frame open
`define DNCAL_STATUS_FRAME_OPEN 4
// STATUS: upload failed
`define DNCAL_STATUS_UPLOAD_FAILED 8
// STATUS: upload open
`define DNCAL_STATUS_UPLOAD_OPEN 16
// STATUS: shift of the active bank
`define DNCAL_STATUS_ACTIVE_BANK_SHIFT 8
// LUT image: magic, little-endian (dncal_core::image::MAGIC)
`define DNCAL_IMAGE_MAGIC 1414286916
// LUT image: version
`define DNCAL_IMAGE_VERSION 1
// LUT image: header bytes
`define DNCAL_IMAGE_HEADER_LEN 16
// LUT image: fractional bits of an entry
`define DNCAL_IMAGE_FRAC_BITS 11
// LUT image: bytes in all
`define DNCAL_IMAGE_LEN 65556
// register Id
`define DNCAL_REG_ID 0
// register Control
`define DNCAL_REG_CONTROL 4
// register Status
`define DNCAL_REG_STATUS 8
// register Width
`define DNCAL_REG_WIDTH 12
// register Height
`define DNCAL_REG_HEIGHT 16
// register States
`define DNCAL_REG_STATES 20
// register FirstColumn
`define DNCAL_REG_FIRST_COLUMN 24
// register OutOfRange
`define DNCAL_REG_OUT_OF_RANGE 28
// register Saturated
`define DNCAL_REG_SATURATED 32
// register Rejected
`define DNCAL_REG_REJECTED 36
// register Frames
`define DNCAL_REG_FRAMES 40
// register LutSwaps
`define DNCAL_REG_LUT_SWAPS 44
// register Incomplete
`define DNCAL_REG_INCOMPLETE 48
// register FifoOverflow
`define DNCAL_REG_FIFO_OVERFLOW 52
`endif
