// The frame grabber's correction datapath: the RTL of what `fpga-model` models cycle by
// cycle (fpga-model/src/datapath.rs), held to it and to the core bit for bit and cycle for
// cycle by fpga-model/tests/rtl_cosim.rs (Verilator).
//
// One pixel clock (`clk`) moves TAPS pixels a beat through:
//   input   a beat of 1..TAPS pixels of one line; each pixel's sum address is
//           (state * height + row) * width + column, its ADC (first_column + column) mod 4;
//   FIFO    FIFO_DEPTH entries (a power of two), of which `fifo_limit` are used; a pixel
//           that finds it full is dropped and counted (`fifo_overflows`), never silently;
//   lookup  up to TAPS pixels a cycle leave the FIFO, as many as the sum memory's bandwidth
//           allows (`mem_words` 32-bit words a cycle, two a pixel: a token bucket that holds
//           one cycle's words, two when a cycle brings one, one more when it brings an odd
//           number, as the model's); each reads its LUT entry from block RAM (one replica a
//           lane, one cycle of latency) in the bank it entered with;
//   issue   the next cycle, its sum's read is issued to the external memory;
//   write   `mem_latency` cycles later the read's data comes back; the entry is added
//           (saturating at 2^32 - 1, each clipped addition counted) and written back in the
//           same cycle.
// A pixel's latency, FIFO entry to write-back, is the memory's plus two cycles.
//
// The memory port (the co-simulation harness's model, hdl/tb/harness.cpp): a write and a
// read of one cycle take effect at its rising edge, the write first; a read's data is on
// `mem_rd_data` at the edge `mem_latency - 1` cycles after that one, where the port's
// register takes it, so that the write stage has it `mem_latency` cycles after the issue.
// A sum whose earlier read-modify-write is still in flight would be read stale: the write
// stage forwards the newest value written to the same address since the read (the last
// `mem_latency - 1` cycles' writes, then the lanes before it in the same cycle), and counts
// each such pixel in `rmw_hazards`, the model's count of where hardware needs forwarding.
//
// LUT banks: two, each 4 ADCs x 2^CODE_BITS entries of ENTRY_BITS bits. The upload port
// (`cfg_clk`, the configuration side's clock: dncal_regs.v) writes the staging bank, the
// one `active_bank` does not name; a pixel looks up the bank `active_bank` named when it
// entered (pixels already queued keep theirs). Uploading over a bank queued pixels still
// use is the model's `lut_overwrite_hazards`.
`default_nettype none
`include "dncal_consts.vh"

// (ADCs and states are powers of two: column c's ADC is the low bits of c.)
`define DNCAL_ADC_BITS $clog2(`DNCAL_ADCS)
`define DNCAL_STATE_BITS $clog2(`DNCAL_MAX_STATES)

module dncal_datapath #(
    parameter integer TAPS = 4,
    parameter integer FIFO_AW = 12,
    parameter integer MAX_LATENCY = 64,
    parameter integer ADDR_W = `DNCAL_ADDR_W,
    parameter integer CODE_BITS = `DNCAL_CODE_BITS,
    parameter integer ENTRY_BITS = `DNCAL_ENTRY_BITS,
    parameter integer ADC_BITS = `DNCAL_ADC_BITS,
    parameter integer STATE_BITS = `DNCAL_STATE_BITS,
    // A directory holding `lut_adc0.hex` .. `lut_adc3.hex` as `dncal fpga-size --lut L.fits
    // -o DIR` writes them: bank 0's tables (the active bank after reset) from the start;
    // empty: both banks start with the ideal tables, as the model's.
    parameter LUT_HEX = ""
) (
    input  wire                      clk,
    input  wire                      rst,
    // Configuration, static while frames stream.
    input  wire [15:0]               width,
    input  wire [15:0]               height,
    // (The sensor column of a line's first pixel: only its phase mod 4 picks the ADC.)
    /* verilator lint_off UNUSEDSIGNAL */
    input  wire [15:0]               first_column,
    /* verilator lint_on UNUSEDSIGNAL */
    // What a board fixes, sampled while `rst` is high.
    input  wire [6:0]                mem_latency_in,   // 1..MAX_LATENCY
    input  wire [7:0]                mem_words_in,     // 1..255
    input  wire [FIFO_AW:0]          fifo_limit_in,    // TAPS..2^FIFO_AW
    // Pixels.
    input  wire                      sof,           // first cycle of a frame; `state` valid
    input  wire [STATE_BITS-1:0]     state,
    input  wire                      eof,           // last cycle of a frame
    input  wire                      beat_valid,    // line-valid: a beat this cycle
    input  wire [3:0]                beat_count,    // its pixels, 1..TAPS
    input  wire [16*TAPS-1:0]        beat_data,     // pixel k at bits 16k+15..16k
    input  wire                      active_bank,   // the bank pixels entering now use
    input  wire [7:0]                clear_count,   // a change: clear the per-state frame counts
    // LUT upload (configuration clock): the staging bank's entry of `cfg_adc`, `cfg_code`.
    input  wire                      cfg_clk,
    input  wire                      cfg_we,
    input  wire [ADC_BITS-1:0]       cfg_adc,
    input  wire [CODE_BITS-1:0]      cfg_code,
    input  wire [ENTRY_BITS-1:0]     cfg_entry,
    // Sum memory.
    output wire [TAPS-1:0]           mem_rd_en,
    output wire [ADDR_W*TAPS-1:0]    mem_rd_addr,
    input  wire [32*TAPS-1:0]        mem_rd_data,
    output reg  [TAPS-1:0]           mem_wr_en,
    output reg  [ADDR_W*TAPS-1:0]    mem_wr_addr,
    output reg  [32*TAPS-1:0]        mem_wr_data,
    // Status.
    output reg  [31:0]               pixels,
    output reg  [31:0]               fifo_overflows,
    output reg  [31:0]               out_of_range,
    output reg  [31:0]               saturated,
    output reg  [31:0]               rmw_hazards,
    output reg  [FIFO_AW:0]          fifo_high_water,
    output wire [32*`DNCAL_MAX_STATES-1:0] frames,  // per modulation state
    output reg  [31:0]               frames_total,  // frames ended (not cleared)
    output reg                       frame_open,    // between a frame's first and last cycle
    output wire                      busy,          // pixels in the FIFO or the pipeline
    // A test bench's view: the active bank's entry of {ADC, code} `dbg_lut_addr` (lane 0's
    // copy, read without a clock; zero where SYNTHESIS is defined, as Yosys defines it).
    input  wire [ADC_BITS+CODE_BITS-1:0] dbg_lut_addr,
    output wire [ENTRY_BITS-1:0]     dbg_lut_entry
);
    localparam integer DEPTH = 1 << FIFO_AW;
    reg [6:0]       mem_latency;
    reg [7:0]       mem_words;
    reg [FIFO_AW:0] fifo_limit;
    always @(posedge clk)
        if (rst) begin
            mem_latency <= mem_latency_in;
            mem_words <= mem_words_in;
            fifo_limit <= fifo_limit_in;
        end
    // The memory's read data, registered at the port: a read's data is captured at the edge
    // `mem_latency - 1` cycles after the one that issued it (the same edge when the latency
    // is 1), and is the write stage's in the cycle after.
    reg [32*TAPS-1:0] rd_q;
    always @(posedge clk) rd_q <= mem_rd_data;
    localparam integer LUT_AW = 1 + ADC_BITS + CODE_BITS;
    localparam [CODE_BITS-1:0] TOP = {CODE_BITS{1'b1}};

    // ---- Frame position ------------------------------------------------------------
    reg  [STATE_BITS-1:0] cur_state;
    reg  [ADDR_W-1:0] row_base;   // (state * height + row) * width
    reg  [15:0]       col;
    wire [31:0]       frame_pixels = {16'd0, width} * {16'd0, height};
    // (Only the address's ADDR_W bits are kept: a geometry whose sums exceed the sum
    // memory is refused where it is set, as the model's `Config::holds`.)
    /* verilator lint_off UNUSEDSIGNAL */
    wire [32+STATE_BITS-1:0] state_base = {32'd0, state} * {{STATE_BITS{1'b0}}, frame_pixels};
    /* verilator lint_on UNUSEDSIGNAL */
    wire [ADDR_W-1:0] base_now = sof ? state_base[ADDR_W-1:0] : row_base;
    wire [15:0]       col_now = sof ? 16'd0 : col;
    wire [STATE_BITS-1:0] state_now = sof ? state : cur_state;
    wire              in_bank = active_bank;
    reg  [7:0]        clear_seen;
    wire [16:0]       col_end = {1'b0, col_now} + {13'd0, beat_count};

    // ---- FIFO ----------------------------------------------------------------------
    reg [ADDR_W-1:0]    q_addr [0:DEPTH-1];
    reg [CODE_BITS-1:0] q_code [0:DEPTH-1];
    reg [ADC_BITS-1:0]  q_adc  [0:DEPTH-1];
    reg                 q_oor  [0:DEPTH-1];
    reg                 q_bank [0:DEPTH-1];
    reg [FIFO_AW-1:0]   head;
    reg [FIFO_AW:0]     count;
    reg [8:0]           tokens;

    // The token bucket and how many pixels leave the FIFO this cycle.
    wire [8:0] words = {1'b0, mem_words};
    wire [8:0] cap = (words > 9'd2 ? words : 9'd2) + {8'd0, mem_words[0]};
    wire [9:0] filled = {1'b0, tokens} + {1'b0, words};
    wire [8:0] t1 = filled > {1'b0, cap} ? cap : filled[8:0];
    // min(TAPS, count, t1 / 2)
    wire [8:0] by_tokens = {1'b0, t1[8:1]};
    wire [FIFO_AW+9:0] count_wide = {9'd0, count};
    wire [8:0] by_count = count_wide > {{(FIFO_AW + 1){1'b0}}, 9'd8} ? 9'd8 : count_wide[8:0];
    wire [8:0] by_taps = TAPS[8:0];
    wire [8:0] least = by_tokens < by_count ? by_tokens : by_count;
    wire [3:0] npop = least < by_taps ? least[3:0] : by_taps[3:0];
    wire [FIFO_AW:0] after_pop = count - {{(FIFO_AW - 3){1'b0}}, npop};
    wire [FIFO_AW:0] room = fifo_limit > after_pop ? fifo_limit - after_pop : {(FIFO_AW + 1){1'b0}};
    wire [3:0] offered = beat_valid ? beat_count : 4'd0;
    wire [3:0] accepted = {{(FIFO_AW - 3){1'b0}}, offered} > room ? room[3:0] : offered;

    // The ideal table's entry of `code`: (code + 1/2) DN in units of 2^-(ENTRY_BITS -
    // CODE_BITS) DN (the core's `LutEntry::ideal`).
    function automatic [ENTRY_BITS-1:0] ideal(input [CODE_BITS-1:0] code);
        ideal = {code, 1'b1, {(ENTRY_BITS - CODE_BITS - 1){1'b0}}};
    endfunction

    // ---- LUT banks: one replica a lane ---------------------------------------------
    reg [TAPS-1:0]         lk_valid;
    reg [ADDR_W-1:0]       lk_addr  [0:TAPS-1];
    reg [ENTRY_BITS-1:0]   lk_entry [0:TAPS-1];
    wire [TAPS-1:0]        popped_oor;   // the pixels leaving the FIFO with a code above the top
    genvar g;
    generate
        for (g = 0; g < TAPS; g = g + 1) begin : lane
            reg [ENTRY_BITS-1:0] lut [0:(1 << LUT_AW) - 1];
            wire [FIFO_AW-1:0] at = head + g[FIFO_AW-1:0];
            always @(posedge cfg_clk)
                if (cfg_we) lut[{~active_bank, cfg_adc, cfg_code}] <= cfg_entry;
            if (LUT_HEX == "") begin : ideal_tables
                // Without files, both banks start with the ideal tables, as the model's
                // and the core's: code k reads k + 1/2 DN.
                integer i;
                initial
                    for (i = 0; i < (1 << LUT_AW); i = i + 1)
                        lut[i] = ideal(i[CODE_BITS-1:0]);
            end else begin : initial_tables
                integer a;
                initial
                    for (a = 0; a < (1 << ADC_BITS); a = a + 1)
                        $readmemh({LUT_HEX, "/lut_adc", 8'd48 + a[7:0], ".hex"}, lut,
                                  a << CODE_BITS, ((a + 1) << CODE_BITS) - 1);
            end
            always @(posedge clk) begin
                lk_entry[g] <= lut[{q_bank[at], q_adc[at], q_code[at]}];
                lk_addr[g]  <= q_addr[at];
            end
            assign popped_oor[g] = g < npop && q_oor[at];
            if (g == 0) begin : view
`ifdef SYNTHESIS
                // (An unclocked read port would keep the table out of block RAM.)
                assign dbg_lut_entry = {ENTRY_BITS{1'b0}};
`else
                assign dbg_lut_entry = lut[{active_bank, dbg_lut_addr}];
`endif
            end
            assign mem_rd_en[g] = lk_valid[g];
            assign mem_rd_addr[ADDR_W*g +: ADDR_W] = lk_addr[g];
            assign lk_addr_v[ADDR_W*g +: ADDR_W] = lk_addr[g];
            assign lk_entry_v[ENTRY_BITS*g +: ENTRY_BITS] = lk_entry[g];
        end
    endgenerate

    // ---- Read-modify-write pipeline: stage s holds the pixels issued s cycles ago ----
    // Stage s (1 to MAX_LATENCY) at lane k: bits [W*(TAPS*(s-1) + k) +: W] of a W-bit field.
    localparam integer PW = TAPS * MAX_LATENCY;
    reg [PW-1:0]          p_valid;
    reg [ADDR_W*PW-1:0]   p_addr;
    reg [ENTRY_BITS*PW-1:0] p_entry;
    // What was written s cycles ago (s = 1 the cycle before this one), likewise.
    reg [PW-1:0]          h_valid;
    reg [ADDR_W*PW-1:0]   h_addr;
    reg [32*PW-1:0]       h_value;
    // The issued pixels `mem_latency` cycles ago: the write stage's.
    wire [6:0] wl = mem_latency - 7'd1;
    wire [TAPS-1:0]            w_valid = p_valid[TAPS*wl +: TAPS];
    wire [ADDR_W*TAPS-1:0]     w_addr  = p_addr[ADDR_W*TAPS*wl +: ADDR_W*TAPS];
    wire [ENTRY_BITS*TAPS-1:0] w_entry = p_entry[ENTRY_BITS*TAPS*wl +: ENTRY_BITS*TAPS];
    wire [ADDR_W*TAPS-1:0]     lk_addr_v;
    wire [ENTRY_BITS*TAPS-1:0] lk_entry_v;

    // The write stage: the pixels issued `mem_latency` cycles ago, their sums forwarded.
    reg [TAPS-1:0] clipped;
    reg [TAPS-1:0] forwarded;
    always @* begin : write_stage
        integer k, j, s;
        reg [ADDR_W-1:0] a;
        reg [31:0] base;
        reg [32:0] total;
        mem_wr_en = {TAPS{1'b0}};
        mem_wr_addr = {(ADDR_W * TAPS){1'b0}};
        mem_wr_data = {(32 * TAPS){1'b0}};
        clipped = {TAPS{1'b0}};
        forwarded = {TAPS{1'b0}};
        for (k = 0; k < TAPS; k = k + 1) begin
            a = w_addr[ADDR_W*k +: ADDR_W];
            base = rd_q[32*k +: 32];
            // Oldest first, so that the newest write to the address is the one kept.
            for (s = MAX_LATENCY; s >= 1; s = s - 1)
                if (s < {25'd0, mem_latency})
                    for (j = 0; j < TAPS; j = j + 1)
                        if (h_valid[TAPS*(s-1) + j] && h_addr[ADDR_W*(TAPS*(s-1) + j) +: ADDR_W] == a) begin
                            base = h_value[32*(TAPS*(s-1) + j) +: 32];
                            forwarded[k] = 1'b1;
                        end
            for (j = 0; j < k; j = j + 1)
                if (mem_wr_en[j] && mem_wr_addr[ADDR_W*j +: ADDR_W] == a) begin
                    base = mem_wr_data[32*j +: 32];
                    forwarded[k] = 1'b1;
                end
            total = {1'b0, base} + {{(33 - ENTRY_BITS){1'b0}}, w_entry[ENTRY_BITS*k +: ENTRY_BITS]};
            clipped[k] = w_valid[k] && total[32];
            forwarded[k] = forwarded[k] && w_valid[k];
            mem_wr_en[k] = w_valid[k];
            mem_wr_addr[ADDR_W*k +: ADDR_W] = a;
            mem_wr_data[32*k +: 32] = total[32] ? 32'hFFFF_FFFF : total[31:0];
        end
    end

    // ---- Counters --------------------------------------------------------------------
    reg [31:0] frame_count [0:`DNCAL_MAX_STATES-1];
    generate
        for (g = 0; g < `DNCAL_MAX_STATES; g = g + 1) begin : frame_out
            assign frames[32*g +: 32] = frame_count[g];
        end
    endgenerate

    function automatic [31:0] sat_add(input [31:0] x, input [3:0] n);
        reg [32:0] t;
        begin
            t = {1'b0, x} + {29'd0, n};
            sat_add = t[32] ? 32'hFFFF_FFFF : t[31:0];
        end
    endfunction

    function automatic [3:0] ones(input [TAPS-1:0] v);
        integer k;
        begin
            ones = 4'd0;
            for (k = 0; k < TAPS; k = k + 1) ones = ones + {3'd0, v[k]};
        end
    endfunction

    reg in_flight;
    always @* begin : flight
        integer s;
        in_flight = |lk_valid;
        for (s = 1; s <= MAX_LATENCY; s = s + 1)
            if (s <= {25'd0, mem_latency}) in_flight = in_flight | (|p_valid[TAPS*(s-1) +: TAPS]);
    end
    assign busy = count != 0 || in_flight;

    wire [FIFO_AW-1:0] tail = head + count[FIFO_AW-1:0];
    wire [FIFO_AW:0] count_next = after_pop + {{(FIFO_AW - 3){1'b0}}, accepted};

    always @(posedge clk) begin : step
        integer k;
        reg [ADC_BITS-1:0] c;
        if (rst) begin
            head <= {FIFO_AW{1'b0}};
            count <= {(FIFO_AW + 1){1'b0}};
            tokens <= 9'd0;
            lk_valid <= {TAPS{1'b0}};
            p_valid <= {PW{1'b0}};
            h_valid <= {PW{1'b0}};
            pixels <= 32'd0;
            fifo_overflows <= 32'd0;
            out_of_range <= 32'd0;
            saturated <= 32'd0;
            rmw_hazards <= 32'd0;
            fifo_high_water <= {(FIFO_AW + 1){1'b0}};
            for (k = 0; k < `DNCAL_MAX_STATES; k = k + 1) frame_count[k] <= 32'd0;
            clear_seen <= clear_count;
            frames_total <= 32'd0;
            frame_open <= 1'b0;
            cur_state <= {STATE_BITS{1'b0}};
            row_base <= {ADDR_W{1'b0}};
            col <= 16'd0;
        end else begin
            // Write-backs (the memory takes them at this edge) and the history.
            saturated <= sat_add(saturated, ones(clipped));
            rmw_hazards <= sat_add(rmw_hazards, ones(forwarded));
            h_valid <= {h_valid[PW-TAPS-1:0], mem_wr_en};
            h_addr <= {h_addr[ADDR_W*(PW-TAPS)-1:0], mem_wr_addr};
            h_value <= {h_value[32*(PW-TAPS)-1:0], mem_wr_data};
            // Issue: last cycle's lookups.
            p_valid <= {p_valid[PW-TAPS-1:0], lk_valid};
            p_addr <= {p_addr[ADDR_W*(PW-TAPS)-1:0], lk_addr_v};
            p_entry <= {p_entry[ENTRY_BITS*(PW-TAPS)-1:0], lk_entry_v};
            // Lookups (the replicas' reads above) of the pixels leaving the FIFO.
            for (k = 0; k < TAPS; k = k + 1) lk_valid[k] <= k < npop;
            out_of_range <= sat_add(out_of_range, ones(popped_oor));
            tokens <= t1 - {4'd0, npop, 1'b0};
            head <= head + {{(FIFO_AW - 4){1'b0}}, npop};
            // Input, behind the pops.
            for (k = 0; k < TAPS; k = k + 1)
                if (k < accepted) begin
                    c = first_column[ADC_BITS-1:0] + col_now[ADC_BITS-1:0] + k[ADC_BITS-1:0];
                    q_addr[tail + k[FIFO_AW-1:0]] <= base_now + {{(ADDR_W - 16){1'b0}}, col_now} + k[ADDR_W-1:0];
                    q_code[tail + k[FIFO_AW-1:0]] <= beat_data[16*k+CODE_BITS +: 16-CODE_BITS] != 0 ? TOP : beat_data[16*k +: CODE_BITS];
                    q_oor[tail + k[FIFO_AW-1:0]] <= beat_data[16*k+CODE_BITS +: 16-CODE_BITS] != 0;
                    q_adc[tail + k[FIFO_AW-1:0]] <= c[1:0];
                    q_bank[tail + k[FIFO_AW-1:0]] <= in_bank;
                end
            count <= count_next;
            pixels <= sat_add(pixels, accepted);
            fifo_overflows <= sat_add(fifo_overflows, offered - accepted);
            if (count_next > fifo_high_water) fifo_high_water <= count_next;
            // Frame position: the next beat's column and row.
            cur_state <= state_now;
            if (beat_valid) begin
                if (col_end >= {1'b0, width}) begin
                    col <= 16'd0;
                    row_base <= base_now + {{(ADDR_W - 16){1'b0}}, width};
                end else begin
                    col <= col_end[15:0];
                    row_base <= base_now;
                end
            end else begin
                col <= col_now;
                row_base <= base_now;
            end
            // (A clear, then the frame that ends in this cycle.)
            // (A count, not a toggle: two clears between pixel clocks are still a clear.)
            if (clear_seen != clear_count) begin
                clear_seen <= clear_count;
                for (k = 0; k < `DNCAL_MAX_STATES; k = k + 1)
                    frame_count[k] <= (eof && k == {{(32 - STATE_BITS){1'b0}}, state_now}) ? 32'd1 : 32'd0;
            end else if (eof) begin
                frame_count[state_now] <= sat_add(frame_count[state_now], 4'd1);
            end
            if (eof) frames_total <= sat_add(frames_total, 4'd1);
            frame_open <= (sof || frame_open) && !eof;
        end
    end
endmodule

`default_nettype wire
