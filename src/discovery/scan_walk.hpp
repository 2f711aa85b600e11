// The walk over a Modbus coupler's complex area (walk(), scan.cpp), one terminal at a time: where
// its register window can be, its R8, its type, the registers that decide its image, and the check
// that they put the window where it answered. Private to the discovery layer.
#pragma once
#include <cstdint>
#include <optional>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/scan.hpp"

namespace kscfg::scan_walk {

// Whether two register windows are at the same bytes.
bool same_window(const RegisterWindow& a, const RegisterWindow& b);

// The next terminal as a probe: one channel through the first window its register value can be
// in, and the windows it can be in (the coupler's alignment's first).
struct Probe {
  TerminalImage t;
  std::vector<RegisterWindow> cands;
};

// The next terminal's control/status byte, and where its register value can be: after a
// reserved byte when the coupler aligns words (KL6001 alternative format, KL5101), or right
// after the control/status byte (KL6001 standard format: CT/ST, D0, D1, ... whatever the
// alignment, seed KL6001 annex). The terminal's R8 tells which. None when neither window fits in
// the complex area (co output, ci input bytes).
std::optional<Probe> next_probe(const ScanResult& r, const ImageFormat& probe, std::size_t out, std::size_t in,
                                std::size_t co, std::size_t ci);

// Stations come in runs of one type. A terminal after one that answered through window `win` of
// type `prev` is read as one more of them: R8 and prev's registers that decide the image in one
// program through the same kind of window (reads change nothing on a terminal), each request sent
// with the poll for the one before, the control byte back with the last. Taken only when R8 names
// a one-channel type decided by those same registers and its layout from them puts its window
// where it answered; otherwise nothing is kept and the terminal is walked as before.
bool walk_as_before(ScanResult& r, Engine& engine, const Catalog& catalog, const SessionOptions& so, TerminalImage t,
                    const TerminalType& prev, const RegisterWindow& win);

// R8 through the probe's first window, and through the second one when there is one. A terminal
// that does not answer is named.
std::vector<std::uint16_t> read_r8(RegisterSession& s, Link& link, const Probe& p);

// What R8 told: the type, the window it answered through and its R8 (no type: the catalog knows
// none of the values read).
struct Answer {
  const TerminalType* type = nullptr;
  RegisterWindow win;
  std::uint16_t r8 = 0;
};

// The first of `values` the catalog knows, the window it came through and its R8.
Answer identify(const Catalog& catalog, const Probe& p, const std::vector<std::uint16_t>& values);

// The error for a terminal whose R8 (through every window read) the catalog does not know.
Error unknown_type(const Probe& p, const std::vector<std::uint16_t>& values);

// The registers that decide the image, channel by channel (a channel's place depends on the
// channels before it), into the last terminal's registers. Channel 1 through the window that
// answered, in the probe's session when that is the window probed.
void read_mapping_registers(ScanResult& r, Engine& engine, const Catalog& catalog, const SessionOptions& so,
                            const Probe& p, const Answer& a, std::optional<RegisterSession>& probe_session);

// The last terminal's layout from what it holds must put the window where it answered.
void check_answered_window(const ScanResult& r, const Catalog& catalog, const Answer& a, unsigned position);

}  // namespace kscfg::scan_walk
