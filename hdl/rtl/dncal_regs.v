// The register map and LUT upload of dncal_core::regs, answered on an SPI slave: the RTL of
// fpga-model/src/spi.rs, which the core's own driver (dncal_core::driver) configures.
//
// Clock: `clk`, the configuration side's (the datapath's `cfg_clk`). SPI mode 0 (MOSI
// sampled on SCK's rising edge, MISO changed on its falling edge, most significant bit
// first), SCK, MOSI and CS# synchronized into `clk` (two flip-flops each). MISO changes
// about three `clk` cycles after SCK falls, so SCK must be at most a sixth of `clk` (an
// independent review measured a quarter failing: a read's bits came one late); the
// co-simulation runs it at an eighth.
//
// A frame is the bytes of one chip-select assertion (the rules are dncal_core::regs'):
//   WRITE_REG  cmd, addr, value (u32 LE), crc8                7 bytes
//   READ_REG   cmd, addr, crc8, then 7 bytes clocked back:    value (u32 LE), count (u16 LE), crc8
//   LUT_DATA   cmd, offset (u32 LE), len (u16 LE), len bytes
// crc8 is CRC-8/SMBUS (polynomial 0x07, initial 0). A frame is refused (nothing changes, it
// is not counted, an open upload fails, and every WRITE_REG and LUT_DATA is refused until
// the next accepted READ_REG) on a bad CRC, a wrong length, an unknown command or register,
// or a chunk out of order, too long or without an open upload. A read's response is
// decided when its third byte arrives and clocked out from the fourth; a refused read
// leaves MISO high (0xFF). Where the model refuses a read whose response the host clocked
// fewer or more than 7 bytes of, the RTL has already sent those bytes: the read is refused
// (not counted, the hold set) all the same.
//
// The LUT image (dncal_core::image) streams into the staging bank as it arrives: the
// header against the expected one when its last byte arrives, every entry below 2^ENTRY_BITS and not below its
// predecessor within an ADC, the length, and the CRC-32 (IEEE 802.3) trailer; the first
// error fails the upload. LUT_END validates (STATUS: staging valid or upload failed);
// LUT_COMMIT validates and, if valid, activates the staging bank at once when no frame
// is open (otherwise when the open frame ends).
`default_nettype none
`include "dncal_consts.vh"

module dncal_regs #(
    parameter integer CODE_BITS = `DNCAL_CODE_BITS,
    parameter integer ENTRY_BITS = `DNCAL_ENTRY_BITS,
    parameter integer ADC_BITS = $clog2(`DNCAL_ADCS),
    parameter integer SUM_WORDS_LOG2 = `DNCAL_ADDR_W
) (
    input  wire                  clk,
    input  wire                  rst,
    // SPI.
    input  wire                  spi_sck,
    input  wire                  spi_cs_n,
    input  wire                  spi_mosi,
    output reg                   spi_miso,
    // The geometry registers.
    output reg  [15:0]           width,
    output reg  [15:0]           height,
    output reg  [3:0]            states,
    output reg  [15:0]           first_column,
    // The LUT banks: the active one, and the staging bank's write port.
    output reg                   active_bank,
    output reg                   lut_we,
    output reg  [ADC_BITS-1:0]   lut_adc,
    output reg  [CODE_BITS-1:0]  lut_code,
    output reg  [ENTRY_BITS-1:0] lut_entry,
    // Counts the clears of the sums and per-state frame counts (a new geometry,
    // CLEAR_SUMS), modulo 256.
    output reg  [7:0]            clear_count,
    // From the datapath.
    input  wire                  frame_open,
    input  wire [31:0]           out_of_range,
    input  wire [31:0]           saturated,
    input  wire [31:0]           frames,
    input  wire [31:0]           fifo_overflows,
    // A test bench's view, not a frame (not counted): the value a read of `dbg_addr` returns.
    input  wire [7:0]            dbg_addr,
    output wire [31:0]           dbg_value
);
    localparam integer CODES = 1 << CODE_BITS;
    localparam integer ENTRIES = `DNCAL_ADCS * CODES;
    localparam integer HEADER_LEN = `DNCAL_IMAGE_HEADER_LEN;
    localparam integer ENTRIES_END = HEADER_LEN + 4 * ENTRIES;
    localparam integer IMAGE_LEN = ENTRIES_END + 4;
    localparam [63:0] SUM_WORDS = 64'd1 << SUM_WORDS_LOG2;

    // ---- CRCs ------------------------------------------------------------------------
    function automatic [7:0] crc8(input [7:0] crc, input [7:0] b);
        integer i;
        reg [7:0] c;
        begin
            c = crc ^ b;
            for (i = 0; i < 8; i = i + 1) c = c[7] ? {c[6:0], 1'b0} ^ 8'h07 : {c[6:0], 1'b0};
            crc8 = c;
        end
    endfunction

    // CRC-32/ISO-HDLC, reflected, on the register before the final inversion.
    function automatic [31:0] crc32(input [31:0] crc, input [7:0] b);
        integer i;
        reg [31:0] c;
        begin
            c = crc ^ {24'd0, b};
            for (i = 0; i < 8; i = i + 1) c = c[0] ? {1'b0, c[31:1]} ^ 32'hEDB8_8320 : {1'b0, c[31:1]};
            crc32 = c;
        end
    endfunction

    // The image header this device takes, byte by byte.
    function automatic [7:0] header_byte(input [3:0] i);
        reg [31:0] magic, count;
        begin
            magic = `DNCAL_IMAGE_MAGIC;
            count = ENTRIES;
            case (i)
                4'd0: header_byte = magic[7:0];
                4'd1: header_byte = magic[15:8];
                4'd2: header_byte = magic[23:16];
                4'd3: header_byte = magic[31:24];
                4'd4: header_byte = `DNCAL_IMAGE_VERSION;
                4'd5: header_byte = 8'd0;
                4'd6: header_byte = CODE_BITS[7:0];
                4'd7: header_byte = `DNCAL_ADCS;
                4'd8: header_byte = `DNCAL_IMAGE_FRAC_BITS;
                4'd12: header_byte = count[7:0];
                4'd13: header_byte = count[15:8];
                4'd14: header_byte = count[23:16];
                4'd15: header_byte = count[31:24];
                default: header_byte = 8'd0;
            endcase
        end
    endfunction

    function automatic known(input [7:0] addr);
        begin
            case (addr)
                `DNCAL_REG_ID, `DNCAL_REG_CONTROL, `DNCAL_REG_STATUS, `DNCAL_REG_WIDTH,
                `DNCAL_REG_HEIGHT, `DNCAL_REG_STATES, `DNCAL_REG_FIRST_COLUMN,
                `DNCAL_REG_OUT_OF_RANGE, `DNCAL_REG_SATURATED, `DNCAL_REG_REJECTED,
                `DNCAL_REG_FRAMES, `DNCAL_REG_LUT_SWAPS, `DNCAL_REG_INCOMPLETE,
                `DNCAL_REG_FIFO_OVERFLOW: known = 1'b1;
                default: known = 1'b0;
            endcase
        end
    endfunction

    // ---- Staging bank and link state ------------------------------------------------
    localparam [1:0] EMPTY = 2'd0, LOADING = 2'd1, VALID = 2'd2, FAILED = 2'd3;
    reg [1:0]  staging;
    reg        pending;
    reg [31:0] lut_swaps;
    reg [15:0] accepted;
    reg        hold;
    reg        lut_open;       // an upload open on the link
    reg [31:0] lut_received;   // its image bytes so far
    // The loader.
    reg [31:0] pos;
    reg        done;
    reg [23:0] word;           // the entry's or trailer's first three bytes
    reg [31:0] previous;
    reg [31:0] crc;
    reg        header_bad;     // a header byte so far was not the expected one

    wire [31:0] status = {22'd0, 1'b0, active_bank, 3'd0, staging == LOADING, staging == FAILED,
                          frame_open, pending, staging == VALID};

    function automatic [31:0] value_of(input [7:0] addr);
        begin
            case (addr)
                `DNCAL_REG_ID: value_of = `DNCAL_DEVICE_ID;
                `DNCAL_REG_STATUS: value_of = status;
                `DNCAL_REG_WIDTH: value_of = {16'd0, width};
                `DNCAL_REG_HEIGHT: value_of = {16'd0, height};
                `DNCAL_REG_STATES: value_of = {28'd0, states};
                `DNCAL_REG_FIRST_COLUMN: value_of = {16'd0, first_column};
                `DNCAL_REG_OUT_OF_RANGE: value_of = out_of_range;
                `DNCAL_REG_SATURATED: value_of = saturated;
                `DNCAL_REG_FRAMES: value_of = frames;
                `DNCAL_REG_LUT_SWAPS: value_of = lut_swaps;
                `DNCAL_REG_FIFO_OVERFLOW: value_of = fifo_overflows;
                // CONTROL reads 0; the RTL rejects no line and ends no frame early
                // (REJECTED, INCOMPLETE: docs/fpga.md).
                default: value_of = 32'd0;
            endcase
        end
    endfunction

    assign dbg_value = value_of(dbg_addr);

    // ---- SPI bytes ---------------------------------------------------------------------
    reg [2:0] sck_s, cs_s;
    reg [1:0] mosi_s;
    wire sck_rise = sck_s[2:1] == 2'b01;
    wire sck_fall = sck_s[2:1] == 2'b10;
    wire cs_fall = cs_s[2:1] == 2'b10;
    wire cs_rise = cs_s[2:1] == 2'b01;
    wire selected = !cs_s[1];

    reg [2:0]  nbit;
    reg [6:0]  shift;
    reg [15:0] nbytes;         // bytes of the frame so far (saturating)
    reg [7:0]  cmd, addr;
    reg [31:0] value;          // a write's value, or a chunk's offset
    reg [15:0] len;
    reg [7:0]  fcrc, fcrc_prev, last;
    reg        req_ok, lut_ok;
    reg [55:0] resp;

    wire [7:0] byte_in = {shift, mosi_s[1]};
    wire [15:0] n = nbytes;
    wire byte_done = selected && sck_rise && nbit == 3'd7;

    // The response to a read of `addr` with the frame count it will have.
    wire [31:0] resp_value = value_of(addr);
    wire [15:0] resp_count = accepted + 16'd1;
    reg  [7:0]  resp_crc;
    always @* begin : response_crc
        integer i;
        reg [47:0] payload;
        payload = {resp_value[7:0], resp_value[15:8], resp_value[23:16], resp_value[31:24],
                   resp_count[7:0], resp_count[15:8]};
        resp_crc = crc8(crc8(8'd0, `DNCAL_CMD_READ_REG), addr);
        for (i = 5; i >= 0; i = i - 1) resp_crc = crc8(resp_crc, payload[8*i +: 8]);
    end

    // A geometry write's new geometry, and whether the device takes it.
    reg [15:0] g_w, g_h, g_f;
    reg [3:0]  g_s;
    reg        g_ok;
    always @* begin : geometry
        reg [63:0] need;
        g_w = width; g_h = height; g_s = states; g_f = first_column;
        g_ok = 1'b1;
        case (addr)
            `DNCAL_REG_WIDTH: begin g_w = value[15:0]; g_ok = value[31:16] == 16'd0; end
            `DNCAL_REG_HEIGHT: begin g_h = value[15:0]; g_ok = value[31:16] == 16'd0; end
            `DNCAL_REG_STATES: begin g_s = value[3:0]; g_ok = value[31:4] == 28'd0; end
            `DNCAL_REG_FIRST_COLUMN: begin g_f = value[15:0]; g_ok = value[31:16] == 16'd0; end
            default: g_ok = 1'b0;
        endcase
        need = {32'd0, g_w} * {32'd0, g_h} * {60'd0, g_s};
        if (g_w == 16'd0 || g_h == 16'd0 || g_s == 4'd0 || g_s > `DNCAL_MAX_STATES || need > SUM_WORDS)
            g_ok = 1'b0;
    end

    // The loader's verdict on the next image byte `b` at `pos`.
    reg        img_fail, img_write, img_done;
    reg [31:0] img_value;
    always @* begin : loader
        img_fail = 1'b0;
        img_write = 1'b0;
        img_done = 1'b0;
        img_value = {byte_in, word};
        if (pos >= IMAGE_LEN) begin
            img_fail = 1'b1;
        end else if (pos < HEADER_LEN) begin
            // (Judged whole at its last byte, as the core's loader does: STATUS says
            // nothing of a header until it has all arrived.)
            img_fail = pos == HEADER_LEN - 1 && (header_bad || byte_in != header_byte(pos[3:0]));
        end else if (pos[1:0] == 2'd3) begin
            if (pos < ENTRIES_END) begin
                img_write = 1'b1;
                img_fail = img_value >= (32'd1 << ENTRY_BITS)
                    || (((pos - HEADER_LEN) >> 2) % CODES != 0 && img_value < previous);
            end else begin
                img_done = img_value == ~crc;
                img_fail = !img_done;
            end
        end
    end
    // (An entry's index, below the entries' count where it is used: only its low bits.)
    /* verilator lint_off UNUSEDSIGNAL */
    wire [31:0] index = (pos - HEADER_LEN) >> 2;
    /* verilator lint_on UNUSEDSIGNAL */

    always @(posedge clk) begin : step
        reg accept, refuse, swap_now;
        lut_we <= 1'b0;
        if (rst) begin
            sck_s <= 3'b000; cs_s <= 3'b111; mosi_s <= 2'b00;
            spi_miso <= 1'b1;
            width <= 16'd1; height <= 16'd1; states <= 4'd1; first_column <= 16'd0;
            active_bank <= 1'b0;
            clear_count <= 8'd0;
            staging <= EMPTY; pending <= 1'b0; lut_swaps <= 32'd0;
            accepted <= 16'd0; hold <= 1'b0; lut_open <= 1'b0; lut_received <= 32'd0;
            pos <= 32'd0; done <= 1'b0; word <= 24'd0; previous <= 32'd0; crc <= 32'hFFFF_FFFF;
            header_bad <= 1'b0;
            nbit <= 3'd0; shift <= 7'd0; nbytes <= 16'd0; resp <= {56{1'b1}};
            cmd <= 8'd0; addr <= 8'd0; value <= 32'd0; len <= 16'd0;
            fcrc <= 8'd0; fcrc_prev <= 8'd0; last <= 8'd0; req_ok <= 1'b0; lut_ok <= 1'b0;
        end else begin
            sck_s <= {sck_s[1:0], spi_sck};
            cs_s <= {cs_s[1:0], spi_cs_n};
            mosi_s <= {mosi_s[0], spi_mosi};
            if (cs_fall) begin
                nbit <= 3'd0; nbytes <= 16'd0; fcrc <= 8'd0; req_ok <= 1'b0; lut_ok <= 1'b0;
                resp <= {56{1'b1}};
                spi_miso <= 1'b1;
            end
            if (selected && sck_fall) begin
                spi_miso <= resp[55];
                resp <= {resp[54:0], 1'b1};
            end
            if (selected && sck_rise) begin
                shift <= byte_in[6:0];
                nbit <= nbit + 3'd1;
            end
            if (byte_done) begin
                nbytes <= n == 16'hFFFF ? n : n + 16'd1;
                fcrc_prev <= fcrc;
                fcrc <= crc8(fcrc, byte_in);
                last <= byte_in;
                if (n == 16'd0) cmd <= byte_in;
                if (n == 16'd1) addr <= byte_in;
                // A write's value or a chunk's offset, then a chunk's length.
                if (n >= 16'd1 && n <= 16'd4 && cmd == `DNCAL_CMD_LUT_DATA) value <= {byte_in, value[31:8]};
                if (n >= 16'd2 && n <= 16'd5 && cmd == `DNCAL_CMD_WRITE_REG) value <= {byte_in, value[31:8]};
                if (n == 16'd5) len[7:0] <= byte_in;
                if (n == 16'd6) len[15:8] <= byte_in;
                if (n == 16'd2 && cmd == `DNCAL_CMD_READ_REG && byte_in == fcrc && known(addr)) begin
                    req_ok <= 1'b1;
                    resp <= {resp_value[7:0], resp_value[15:8], resp_value[23:16], resp_value[31:24],
                             resp_count[7:0], resp_count[15:8], resp_crc};
                end
                if (n == 16'd6 && cmd == `DNCAL_CMD_LUT_DATA)
                    lut_ok <= !hold && lut_open && value == lut_received
                              && {byte_in, len[7:0]} != 16'd0 && {byte_in, len[7:0]} <= `DNCAL_MAX_LUT_CHUNK;
                // A chunk's image bytes into the loader.
                if (lut_ok && n >= 16'd7 && n < 16'd7 + len && staging == LOADING) begin
                    pos <= pos + 32'd1;
                    if (pos < ENTRIES_END) crc <= crc32(crc, byte_in);
                    word <= {byte_in, word[23:8]};
                    if (pos < HEADER_LEN && byte_in != header_byte(pos[3:0])) header_bad <= 1'b1;
                    if (img_fail) staging <= FAILED;
                    if (img_done) done <= 1'b1;
                    if (img_write && !img_fail) begin
                        lut_we <= 1'b1;
                        lut_adc <= index[CODE_BITS +: ADC_BITS];
                        lut_code <= index[CODE_BITS-1:0];
                        lut_entry <= img_value[ENTRY_BITS-1:0];
                        previous <= img_value;
                    end
                end
            end
            // The frame ends: accepted, or refused.
            swap_now = 1'b0;
            if (cs_rise) begin
                accept = 1'b0;
                refuse = 1'b0;
                case (cmd)
                    `DNCAL_CMD_WRITE_REG: begin
                        if (n == `DNCAL_WRITE_FRAME_LEN && fcrc_prev == last && known(addr) && !hold) accept = 1'b1;
                        else refuse = 1'b1;
                    end
                    `DNCAL_CMD_READ_REG: begin
                        if (req_ok && n == `DNCAL_READ_REQUEST_LEN + `DNCAL_READ_RESPONSE_LEN) accept = 1'b1;
                        else refuse = 1'b1;
                    end
                    `DNCAL_CMD_LUT_DATA: begin
                        if (lut_ok && n == `DNCAL_LUT_HEADER_LEN + len) accept = 1'b1;
                        else refuse = 1'b1;
                    end
                    default: refuse = 1'b1;
                endcase
                if (n == 16'd0) begin
                    accept = 1'b0;
                    refuse = 1'b1;
                end
                if (accept) accepted <= accepted + 16'd1;
                if (accept && cmd == `DNCAL_CMD_READ_REG) hold <= 1'b0;
                if (accept && cmd == `DNCAL_CMD_LUT_DATA) lut_received <= lut_received + {16'd0, len};
                if (refuse) begin
                    hold <= 1'b1;
                    if (lut_open) begin
                        lut_open <= 1'b0;
                        if (staging == LOADING) staging <= FAILED;
                    end
                end
                if (accept && cmd == `DNCAL_CMD_WRITE_REG) begin
                    if (addr == `DNCAL_REG_CONTROL) begin
                        // LUT_BEGIN, then LUT_END / LUT_COMMIT's validation, the activation,
                        // CLEAR_SUMS: in the model's order.
                        if ((value & `DNCAL_CONTROL_LUT_BEGIN) != 0) begin
                            staging <= LOADING; pending <= 1'b0;
                            pos <= 32'd0; done <= 1'b0; crc <= 32'hFFFF_FFFF; previous <= 32'd0;
                            header_bad <= 1'b0;
                            lut_open <= 1'b1; lut_received <= 32'd0;
                        end
                        if ((value & (`DNCAL_CONTROL_LUT_END | `DNCAL_CONTROL_LUT_COMMIT)) != 0) begin
                            lut_open <= 1'b0;
                            if ((value & `DNCAL_CONTROL_LUT_BEGIN) != 0) staging <= FAILED;
                            else if (staging == LOADING) staging <= done ? VALID : FAILED;
                        end
                        if ((value & `DNCAL_CONTROL_LUT_COMMIT) != 0 && (value & `DNCAL_CONTROL_LUT_BEGIN) == 0
                            && (staging == VALID || (staging == LOADING && done))) begin
                            if (frame_open) pending <= 1'b1;
                            else swap_now = 1'b1;
                        end
                        if ((value & `DNCAL_CONTROL_CLEAR_SUMS) != 0) clear_count <= clear_count + 8'd1;
                    end else if (g_ok && {g_w, g_h, g_s, g_f} != {width, height, states, first_column}) begin
                        width <= g_w; height <= g_h; states <= g_s; first_column <= g_f;
                        clear_count <= clear_count + 8'd1;
                    end
                end
            end
            // The activation: at once (a LUT_COMMIT between frames), or, requested while a
            // frame was open, when it ends.
            if (swap_now || (pending && !frame_open && !cs_rise)) begin
                active_bank <= !active_bank;
                staging <= EMPTY;
                pending <= 1'b0;
                lut_swaps <= lut_swaps + 32'd1;
            end
        end
    end
endmodule

`default_nettype wire
