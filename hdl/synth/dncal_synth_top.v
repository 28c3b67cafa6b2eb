// A wrapper for synthesis and place-and-route measurements only: the datapath with every
// input a register loaded from one shift register (fed by the pin `din`) and every output
// registered, then folded by XOR in two more registered stages into one pin (`dout`), so
// that no run-time input is a constant the tools could fold and no logic is left
// unobserved, on a device with far fewer pins than the datapath's ports. What a board
// fixes is fixed here: the memory's latency and bandwidth (`LATENCY`, `WORDS`) and the
// FIFO's size. The configuration clock has a pin of its own, so that the timing report
// gives each clock's maximum. The timing measured is the
// datapath's own, register to register; the pins' paths are not the design's.
`default_nettype none
`include "dncal_consts.vh"

module dncal_synth_top #(
    parameter integer TAPS = 1,
    parameter integer FIFO_AW = 4,
    parameter integer MAX_LATENCY = 8,
    parameter integer LATENCY = MAX_LATENCY,
    parameter integer WORDS = 2 * TAPS,
    parameter integer ADDR_W = `DNCAL_ADDR_W,
    parameter integer CODE_BITS = `DNCAL_CODE_BITS
) (
    input  wire clk,
    input  wire cfg_clk,
    input  wire din,
    output reg  dout
);
    localparam integer STATE_BITS = $clog2(`DNCAL_MAX_STATES);
    localparam integer ADC_BITS = $clog2(`DNCAL_ADCS);
    // The inputs, in the order of the concatenation below.
    localparam integer IN_W = 1 + 3 + 1 + STATE_BITS + 1 + 1 + 4 + 16 * TAPS + 32 * TAPS;
    localparam integer OUT_W = 1 + TAPS + ADDR_W * TAPS + TAPS + ADDR_W * TAPS + 32 * TAPS + 8
                               + 32 * 2 + (FIFO_AW + 1) + 32 * `DNCAL_MAX_STATES + 1;
    reg [IN_W-1:0] in;
    always @(posedge clk) in <= {in[IN_W-2:0], din};

    wire rst, spi_sck, spi_cs_n, spi_mosi, sof, eof, beat_valid;
    wire [STATE_BITS-1:0] state;
    wire [3:0] beat_count;
    wire [16*TAPS-1:0] beat_data;
    wire [32*TAPS-1:0] mem_rd_data;
    assign {rst, spi_sck, spi_cs_n, spi_mosi, sof, state, eof, beat_valid, beat_count, beat_data,
            mem_rd_data} = in;

    wire spi_miso, busy;
    wire [7:0] clear_count;
    wire [TAPS-1:0] mem_rd_en, mem_wr_en;
    wire [ADDR_W*TAPS-1:0] mem_rd_addr, mem_wr_addr;
    wire [32*TAPS-1:0] mem_wr_data;
    wire [31:0] pixels, rmw_hazards;
    wire [FIFO_AW:0] fifo_high_water;
    wire [32*`DNCAL_MAX_STATES-1:0] frames;

    // (The test bench's view is tied off and left unconnected here, as in a design.)
    /* verilator lint_off PINCONNECTEMPTY */
    dncal_top #(
        .TAPS(TAPS), .FIFO_AW(FIFO_AW), .MAX_LATENCY(MAX_LATENCY), .ADDR_W(ADDR_W),
        .CODE_BITS(CODE_BITS)
    ) top (
        .clk(clk), .cfg_clk(cfg_clk), .rst(rst), .mem_latency(LATENCY[6:0]), .mem_words(WORDS[7:0]),
        .fifo_limit({1'b1, {FIFO_AW{1'b0}}}), .spi_sck(spi_sck), .spi_cs_n(spi_cs_n),
        .spi_mosi(spi_mosi), .spi_miso(spi_miso), .sof(sof), .state(state), .eof(eof),
        .beat_valid(beat_valid), .beat_count(beat_count), .beat_data(beat_data),
        .mem_rd_en(mem_rd_en), .mem_rd_addr(mem_rd_addr), .mem_rd_data(mem_rd_data),
        .mem_wr_en(mem_wr_en), .mem_wr_addr(mem_wr_addr), .mem_wr_data(mem_wr_data),
        .clear_count(clear_count), .pixels(pixels), .rmw_hazards(rmw_hazards),
        .fifo_high_water(fifo_high_water), .frames(frames), .busy(busy),
        .dbg_addr(8'd0), .dbg_value(), .dbg_lut_addr({(ADC_BITS + CODE_BITS){1'b0}}),
        .dbg_lut_entry()
    );
    /* verilator lint_on PINCONNECTEMPTY */

    wire [OUT_W-1:0] out = {spi_miso, mem_rd_en, mem_rd_addr, mem_wr_en, mem_wr_addr, mem_wr_data,
                            clear_count, pixels, rmw_hazards, fifo_high_water, frames, busy};
    // (At least one bit of padding: a replication of zero bits is not Verilog-2005.)
    localparam integer GROUPS = OUT_W / 16 + 1;
    reg [OUT_W-1:0] out_r;
    reg [GROUPS-1:0] folded;
    wire [16*GROUPS-1:0] padded = {{(16 * GROUPS - OUT_W){1'b0}}, out_r};
    integer k;
    always @(posedge clk) begin
        out_r <= out;
        for (k = 0; k < GROUPS; k = k + 1) folded[k] <= ^padded[16*k +: 16];
        dout <= ^folded;
    end
endmodule

`default_nettype wire
