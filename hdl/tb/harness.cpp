// Co-simulation harness of hdl/rtl/dncal_top.v (Verilator): the datapath and its register
// map, driven a clock at a time from commands on stdin, each answered with one line on
// stdout. Pixel frames run the pixel clock only, as fpga-model's `Fpga::stream_frame`
// counts its cycles; SPI transactions run the configuration clock only (SCK an eighth of
// it: four cycles low, four high), as the model's register traffic takes no
// pixel cycles. The harness holds the sum memory the RTL reads and writes. Built by
// scripts/hdl.sh for one tap count (-DTAPS); fpga-model/tests/rtl_cosim.rs drives it
// through the core's own SPI driver and compares with the model and the core.
//
// Commands (whitespace-separated words):
//   board LATENCY WORDS LIMIT            the memory's latency and bandwidth, the FIFO's size
//   spi N b_0 ... b_{N-1}                one chip-select assertion clocking N bytes out on
//                                        MOSI; answers `miso` and the N bytes read
//   frame STATE VBLANK HBLANK LINES      then LINES lines: N c_0 ... c_{N-1}
//   drain                                pixel clocks without input until idle
//   sums COUNT                           the first COUNT sums, state-major
//   stats                                the counters, `name=value`
//   peek ADDR                            the value a read of register ADDR would return (no frame)
//   table ADC                            the active bank's table of one ADC
// The sum memory: a cycle's writes, then its reads, at the rising edge; a read's data is
// presented to the port's register at the edge LATENCY - 1 cycles later (dncal_datapath.v). The RTL's clear (a new geometry,
// CLEAR_SUMS) zeroes it at once, as the model's does.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include "Vdncal_top.h"
#include "dncal_consts.h"
#include "verilated.h"

#ifndef TAPS
#error "build with -DTAPS=n (scripts/hdl.sh)"
#endif

static const int kAddrW = DNCAL_ADDR_W;
static const int kCodes = 1 << DNCAL_CODE_BITS;
static const int kRing = 256;

[[noreturn]] static void fail(const std::string& what) {
    std::cerr << "harness: " << what << std::endl;
    std::exit(2);
}

// Bits [lo, lo + w) of a Verilator port of any width.
static uint64_t get(uint64_t v, int lo, int w) { return (v >> lo) & ((w == 64) ? ~0ull : ((1ull << w) - 1)); }
template <std::size_t N>
static uint64_t get(const VlWide<N>& v, int lo, int w) {
    uint64_t out = 0;
    for (int b = 0; b < w; ++b) out |= (uint64_t)((v[(lo + b) / 32] >> ((lo + b) % 32)) & 1u) << b;
    return out;
}
template <class T>
static void put(T& v, int lo, int w, uint64_t x) {
    uint64_t mask = ((w == 64) ? ~0ull : ((1ull << w) - 1)) << lo;
    v = (T)(((uint64_t)v & ~mask) | ((x << lo) & mask));
}
template <std::size_t N>
static void put(VlWide<N>& v, int lo, int w, uint64_t x) {
    for (int b = 0; b < w; ++b) {
        uint32_t bit = (uint32_t)((x >> b) & 1u);
        int i = (lo + b) / 32, s = (lo + b) % 32;
        v[i] = (v[i] & ~(1u << s)) | (bit << s);
    }
}

struct Harness {
    Vdncal_top top;
    std::vector<uint32_t> mem;
    std::vector<std::vector<uint32_t>> ring = std::vector<std::vector<uint32_t>>(kRing, std::vector<uint32_t>(TAPS, 0));
    uint64_t cycle = 0;
    int latency = 1;
    int cleared = 0;

    uint32_t& at(uint64_t a) {
        if (a >= (1ull << kAddrW)) fail("an address beyond the sum memory: " + std::to_string(a));
        if (a >= mem.size()) mem.resize(a + 1, 0);
        return mem[a];
    }

    // One pixel clock with the inputs set by the caller.
    void tick() {
        top.clk = 0;
        top.eval();
        for (int k = 0; k < TAPS; ++k)
            if (get(top.mem_wr_en, k, 1)) at(get(top.mem_wr_addr, kAddrW * k, kAddrW)) = (uint32_t)get(top.mem_wr_data, 32 * k, 32);
        // A read's data goes to the port's register `latency - 1` edges after this one.
        for (int k = 0; k < TAPS; ++k)
            ring[(cycle + latency - 1) % kRing][k] = get(top.mem_rd_en, k, 1) ? at(get(top.mem_rd_addr, kAddrW * k, kAddrW)) : 0;
        for (int k = 0; k < TAPS; ++k) put(top.mem_rd_data, 32 * k, 32, ring[cycle % kRing][k]);
        top.clk = 1;
        top.eval();
        top.sof = 0;
        top.eof = 0;
        top.beat_valid = 0;
        ++cycle;
    }

    // One configuration clock.
    void cfg_tick() {
        top.cfg_clk = 1;
        top.eval();
        top.cfg_clk = 0;
        top.eval();
        if ((int)top.clear_count != cleared) {
            cleared = top.clear_count;
            std::fill(mem.begin(), mem.end(), 0);
        }
    }

    void cfg_ticks(int n) {
        for (int i = 0; i < n; ++i) cfg_tick();
    }

    // One chip-select assertion: the bytes out on MOSI, those read on MISO (sampled just
    // before each rising edge of SCK).
    std::vector<uint8_t> spi(const std::vector<uint8_t>& out) {
        std::vector<uint8_t> in;
        top.spi_cs_n = 0;
        cfg_ticks(8);
        for (uint8_t b : out) {
            uint8_t r = 0;
            for (int bit = 7; bit >= 0; --bit) {
                top.spi_mosi = (b >> bit) & 1;
                cfg_ticks(4);
                r = (uint8_t)((r << 1) | (top.spi_miso & 1));
                top.spi_sck = 1;
                cfg_ticks(4);
                top.spi_sck = 0;
            }
            in.push_back(r);
        }
        cfg_ticks(4);
        top.spi_cs_n = 1;
        cfg_ticks(8);
        return in;
    }

    void reset() {
        top.rst = 1;
        top.spi_cs_n = 1;
        top.spi_sck = 0;
        for (int i = 0; i < 2; ++i) {
            top.clk = 0;
            top.cfg_clk = 0;
            top.eval();
            top.clk = 1;
            top.cfg_clk = 1;
            top.eval();
        }
        top.rst = 0;
        top.clk = 0;
        top.cfg_clk = 0;
        top.eval();
        cleared = top.clear_count;
    }
};

static long word(std::istream& in) {
    long v;
    if (!(in >> v)) fail("expected a number");
    return v;
}

int main(int argc, char** argv) {
    Verilated::commandArgs(argc, argv);
    std::ios::sync_with_stdio(false);
    Harness h;
    h.reset();
    std::string cmd;
    while (std::cin >> cmd) {
        if (cmd == "board") {
            long latency = word(std::cin), words = word(std::cin), limit = word(std::cin);
            if (latency < 1 || latency >= kRing) fail("latency out of range");
            h.top.mem_latency = (uint8_t)latency;
            h.top.mem_words = (uint8_t)words;
            h.top.fifo_limit = (uint32_t)limit;
            h.latency = (int)latency;
            // (The board's constants are sampled during reset.)
            h.reset();
            std::cout << "ok\n";
        } else if (cmd == "spi") {
            long n = word(std::cin);
            std::vector<uint8_t> out;
            for (long i = 0; i < n; ++i) out.push_back((uint8_t)word(std::cin));
            std::vector<uint8_t> in = h.spi(out);
            std::cout << "miso";
            for (uint8_t b : in) std::cout << " " << (int)b;
            std::cout << "\n";
        } else if (cmd == "frame") {
            long state = word(std::cin), vblank = word(std::cin), hblank = word(std::cin), lines = word(std::cin);
            // The frame's cycles: vertical blanking, then each line's beats and blanking.
            struct Cycle { int count; uint16_t px[TAPS]; };
            std::vector<Cycle> cycles((size_t)vblank, Cycle{0, {}});
            for (long l = 0; l < lines; ++l) {
                long n = word(std::cin);
                for (long i = 0; i < n; i += TAPS) {
                    Cycle c{0, {}};
                    for (long k = i; k < n && k < i + TAPS; ++k) c.px[c.count++] = (uint16_t)word(std::cin);
                    cycles.push_back(c);
                }
                for (long b = 0; b < hblank; ++b) cycles.push_back(Cycle{0, {}});
            }
            if (cycles.empty()) fail("a frame without cycles");
            for (size_t i = 0; i < cycles.size(); ++i) {
                h.top.sof = i == 0;
                h.top.state = (uint8_t)state;
                h.top.eof = i + 1 == cycles.size();
                h.top.beat_valid = cycles[i].count > 0;
                h.top.beat_count = (uint8_t)cycles[i].count;
                for (int k = 0; k < TAPS; ++k) put(h.top.beat_data, 16 * k, 16, k < cycles[i].count ? cycles[i].px[k] : 0);
                h.tick();
            }
            std::cout << "ok\n";
        } else if (cmd == "drain") {
            for (;;) {
                h.top.clk = 0;
                h.top.eval();
                if (!h.top.busy) break;
                h.tick();
            }
            std::cout << "ok\n";
        } else if (cmd == "sums") {
            long n = word(std::cin);
            for (long i = 0; i < n; ++i) std::cout << (i ? " " : "") << h.at((uint64_t)i);
            std::cout << "\n";
        } else if (cmd == "peek") {
            // What a read of a register would return, without a frame.
            h.top.dbg_addr = (uint8_t)word(std::cin);
            h.top.eval();
            std::cout << h.top.dbg_value << "\n";
        } else if (cmd == "table") {
            // The active bank's table of one ADC.
            long adc = word(std::cin);
            for (int c = 0; c < kCodes; ++c) {
                h.top.dbg_lut_addr = (uint32_t)((adc << DNCAL_CODE_BITS) | c);
                h.top.eval();
                std::cout << (c ? " " : "") << h.top.dbg_lut_entry;
            }
            std::cout << "\n";
        } else if (cmd == "stats") {
            std::cout << "cycles=" << h.cycle << " pixels=" << h.top.pixels << " rmw_hazards=" << h.top.rmw_hazards
                      << " fifo_high_water=" << h.top.fifo_high_water;
            for (int s = 0; s < DNCAL_MAX_STATES; ++s) std::cout << " frames" << s << "=" << get(h.top.frames, 32 * s, 32);
            std::cout << "\n";
        } else {
            fail("unknown command " + cmd);
        }
        std::cout.flush();
    }
    h.top.final();
    return 0;
}
