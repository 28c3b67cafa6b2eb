// The frame grabber's correction logic: the datapath (dncal_datapath.v) configured through
// the register map on an SPI slave (dncal_regs.v), as the core's driver configures the
// FPGA model. Two clocks: the pixel clock `clk` and the configuration side's `cfg_clk`
// (the SPI slave's oversampling clock). The registers cross into the pixel domain as
// quasi-static levels (the geometry, the active bank, the clear toggle), written only
// between frames; the co-simulation never runs the two clocks at once, so the crossing's
// synchronizers are not modelled yet (docs/fpga.md).
`default_nettype none
`include "dncal_consts.vh"

module dncal_top #(
    parameter integer TAPS = 4,
    parameter integer FIFO_AW = 12,
    parameter integer MAX_LATENCY = 64,
    parameter integer ADDR_W = `DNCAL_ADDR_W,
    parameter integer CODE_BITS = `DNCAL_CODE_BITS,
    parameter LUT_HEX = ""   // the initial tables' directory (dncal_datapath.v)
) (
    input  wire                   clk,
    input  wire                   cfg_clk,
    input  wire                   rst,
    // What a board fixes: the memory's latency and bandwidth, the FIFO's size (sampled
    // while `rst` is high).
    input  wire [6:0]             mem_latency,
    input  wire [7:0]             mem_words,
    input  wire [FIFO_AW:0]       fifo_limit,
    // SPI.
    input  wire                   spi_sck,
    input  wire                   spi_cs_n,
    input  wire                   spi_mosi,
    output wire                   spi_miso,
    // Pixels.
    input  wire                   sof,
    input  wire [$clog2(`DNCAL_MAX_STATES)-1:0] state,
    input  wire                   eof,
    input  wire                   beat_valid,
    input  wire [3:0]             beat_count,
    input  wire [16*TAPS-1:0]     beat_data,
    // Sum memory; `clear_count` counts the clears it is to be zeroed by.
    output wire [TAPS-1:0]        mem_rd_en,
    output wire [ADDR_W*TAPS-1:0] mem_rd_addr,
    input  wire [32*TAPS-1:0]     mem_rd_data,
    output wire [TAPS-1:0]        mem_wr_en,
    output wire [ADDR_W*TAPS-1:0] mem_wr_addr,
    output wire [32*TAPS-1:0]     mem_wr_data,
    output wire [7:0]             clear_count,
    // What the register map does not hold, for the co-simulation's comparison.
    output wire [31:0]            pixels,
    output wire [31:0]            rmw_hazards,
    output wire [FIFO_AW:0]       fifo_high_water,
    output wire [32*`DNCAL_MAX_STATES-1:0] frames,
    output wire                   busy,
    // A test bench's view (tie `dbg_addr` and `dbg_lut_addr` off in a design): the value a
    // register read would return, without a frame; the active bank's LUT entries.
    input  wire [7:0]             dbg_addr,
    output wire [31:0]            dbg_value,
    input  wire [$clog2(`DNCAL_ADCS)+CODE_BITS-1:0] dbg_lut_addr,
    output wire [`DNCAL_ENTRY_BITS-1:0] dbg_lut_entry
);
    localparam integer ENTRY_BITS = `DNCAL_ENTRY_BITS;
    localparam integer ADC_BITS = $clog2(`DNCAL_ADCS);
    wire [15:0] width, height, first_column;
    /* verilator lint_off UNUSEDSIGNAL */
    wire [3:0] states;   // (the datapath takes the state of each frame; the count bounds the sums)
    /* verilator lint_on UNUSEDSIGNAL */
    wire active_bank, lut_we, frame_open;
    wire [ADC_BITS-1:0] lut_adc;
    wire [CODE_BITS-1:0] lut_code;
    wire [ENTRY_BITS-1:0] lut_entry;
    wire [31:0] out_of_range, saturated, frames_total, fifo_overflows;

    dncal_regs #(.CODE_BITS(CODE_BITS), .SUM_WORDS_LOG2(ADDR_W)) regs (
        .clk(cfg_clk), .rst(rst), .spi_sck(spi_sck), .spi_cs_n(spi_cs_n), .spi_mosi(spi_mosi),
        .spi_miso(spi_miso), .width(width), .height(height), .states(states),
        .first_column(first_column), .active_bank(active_bank), .lut_we(lut_we),
        .lut_adc(lut_adc), .lut_code(lut_code), .lut_entry(lut_entry),
        .clear_count(clear_count), .frame_open(frame_open), .out_of_range(out_of_range),
        .saturated(saturated), .frames(frames_total), .fifo_overflows(fifo_overflows),
        .dbg_addr(dbg_addr), .dbg_value(dbg_value)
    );

    dncal_datapath #(
        .TAPS(TAPS), .FIFO_AW(FIFO_AW), .MAX_LATENCY(MAX_LATENCY), .ADDR_W(ADDR_W),
        .CODE_BITS(CODE_BITS), .LUT_HEX(LUT_HEX)
    ) dp (
        .clk(clk), .rst(rst), .width(width), .height(height), .first_column(first_column),
        .mem_latency_in(mem_latency), .mem_words_in(mem_words), .fifo_limit_in(fifo_limit),
        .sof(sof), .state(state), .eof(eof), .beat_valid(beat_valid), .beat_count(beat_count),
        .beat_data(beat_data), .active_bank(active_bank), .clear_count(clear_count),
        .cfg_clk(cfg_clk), .cfg_we(lut_we), .cfg_adc(lut_adc), .cfg_code(lut_code),
        .cfg_entry(lut_entry), .mem_rd_en(mem_rd_en), .mem_rd_addr(mem_rd_addr),
        .mem_rd_data(mem_rd_data), .mem_wr_en(mem_wr_en), .mem_wr_addr(mem_wr_addr),
        .mem_wr_data(mem_wr_data), .pixels(pixels), .fifo_overflows(fifo_overflows),
        .out_of_range(out_of_range), .saturated(saturated), .rmw_hazards(rmw_hazards),
        .fifo_high_water(fifo_high_water), .frames(frames), .frames_total(frames_total),
        .frame_open(frame_open), .busy(busy), .dbg_lut_addr(dbg_lut_addr),
        .dbg_lut_entry(dbg_lut_entry)
    );
endmodule

`default_nettype wire
