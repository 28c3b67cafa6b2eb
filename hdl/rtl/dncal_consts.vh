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
`endif
