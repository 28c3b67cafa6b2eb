// Co-simulation harness of hdl/rtl/dncal_datapath.v (Verilator): drives the datapath a
// pixel clock at a time from a script on stdin, as fpga-model's `Fpga::stream_frame`
// drives its model, and holds the sum memory the RTL reads and writes. Built by
// scripts/hdl.sh for one tap count (-DTAPS); fpga-model/tests/rtl_cosim.rs writes the
// script and compares what this prints with the model and the core.
//
// Script (whitespace-separated words):
//   config W H STATES FIRST LATENCY WORDS LIMIT   geometry and timing; clears the sums
//   lut ADC e_0 ... e_{CODES-1}                    the staging bank's table of one ADC
//   swap                                           the staging bank active from the next cycle
//                                                  (an upload before that cycle replaces it)
//   frame STATE VBLANK HBLANK LINES                then LINES lines: N c_0 ... c_{N-1}
//   drain                                          cycles without input until idle
//   sums                                           prints every sum, state-major, one line
//   stats                                          prints the counters, `name=value`
// The sum memory: a cycle's writes, then its reads, at the rising edge; a read's data is
// presented LATENCY cycles later (see the RTL's header).
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include "Vdncal_datapath.h"
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
    Vdncal_datapath top;
    std::vector<uint32_t> mem;
    std::vector<std::vector<uint32_t>> ring = std::vector<std::vector<uint32_t>>(kRing, std::vector<uint32_t>(TAPS, 0));
    uint64_t cycle = 0;
    int latency = 1;
    bool swap_pending = false;

    // One pixel clock with the inputs set by the caller.
    void tick() {
        top.lut_swap = swap_pending;
        swap_pending = false;
        for (int k = 0; k < TAPS; ++k) put(top.mem_rd_data, 32 * k, 32, ring[cycle % kRing][k]);
        top.clk = 0;
        top.eval();
        for (int k = 0; k < TAPS; ++k)
            if (get(top.mem_wr_en, k, 1)) {
                uint64_t a = get(top.mem_wr_addr, kAddrW * k, kAddrW);
                if (a >= mem.size()) fail("write beyond the sums at " + std::to_string(a));
                mem[a] = (uint32_t)get(top.mem_wr_data, 32 * k, 32);
            }
        for (int k = 0; k < TAPS; ++k) {
            uint32_t v = 0;
            if (get(top.mem_rd_en, k, 1)) {
                uint64_t a = get(top.mem_rd_addr, kAddrW * k, kAddrW);
                if (a >= mem.size()) fail("read beyond the sums at " + std::to_string(a));
                v = mem[a];
            }
            ring[(cycle + latency) % kRing][k] = v;
        }
        top.clk = 1;
        top.eval();
        top.sof = 0;
        top.eof = 0;
        top.beat_valid = 0;
        ++cycle;
    }

    void reset() {
        top.rst = 1;
        top.clk = 0;
        top.eval();
        top.clk = 1;
        top.eval();
        top.rst = 0;
        top.clk = 0;
        top.eval();
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
    h.top.cfg_clk = 0;
    h.reset();
    long width = 0, height = 0, states = 0;
    std::string cmd;
    while (std::cin >> cmd) {
        if (cmd == "config") {
            width = word(std::cin), height = word(std::cin), states = word(std::cin);
            long first = word(std::cin), latency = word(std::cin), words = word(std::cin), limit = word(std::cin);
            if (latency < 1 || latency >= kRing) fail("latency out of range");
            h.top.width = (uint16_t)width;
            h.top.height = (uint16_t)height;
            h.top.first_column = (uint16_t)first;
            h.top.mem_latency = (uint8_t)latency;
            h.top.mem_words = (uint8_t)words;
            h.top.fifo_limit = (uint32_t)limit;
            h.latency = (int)latency;
            h.mem.assign((size_t)(width * height * states), 0);
        } else if (cmd == "lut") {
            // An upload before the last one's swap reached a pixel clock writes the same
            // staging bank again: with no pixel between them the two swaps are one, and the
            // tables active after it are this upload's, as in the model.
            h.swap_pending = false;
            long adc = word(std::cin);
            for (int c = 0; c < kCodes; ++c) {
                h.top.cfg_we = 1;
                h.top.cfg_adc = (uint8_t)adc;
                h.top.cfg_code = (uint16_t)c;
                h.top.cfg_entry = (uint32_t)word(std::cin);
                h.top.cfg_clk = 1;
                h.top.eval();
                h.top.cfg_clk = 0;
                h.top.eval();
            }
            h.top.cfg_we = 0;
        } else if (cmd == "swap") {
            h.swap_pending = true;
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
        } else if (cmd == "drain") {
            for (;;) {
                h.top.clk = 0;
                h.top.eval();
                if (!h.top.busy) break;
                h.tick();
            }
        } else if (cmd == "sums") {
            for (size_t i = 0; i < h.mem.size(); ++i) std::cout << (i ? " " : "") << h.mem[i];
            std::cout << "\n";
        } else if (cmd == "stats") {
            std::cout << "cycles=" << h.cycle << " pixels=" << h.top.pixels << " fifo_overflows=" << h.top.fifo_overflows
                      << " out_of_range=" << h.top.out_of_range << " saturated=" << h.top.saturated
                      << " rmw_hazards=" << h.top.rmw_hazards << " fifo_high_water=" << h.top.fifo_high_water;
            for (int s = 0; s < DNCAL_MAX_STATES; ++s) std::cout << " frames" << s << "=" << get(h.top.frames, 32 * s, 32);
            std::cout << "\n";
        } else {
            fail("unknown command " + cmd);
        }
    }
    std::cout.flush();
    h.top.final();
    return 0;
}
