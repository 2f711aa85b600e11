// The adapter side of slcan (emulator/slcan_adapter.hpp).
#include "kscfg/emulator/slcan_adapter.hpp"

#include <fmt/format.h>

#include <cctype>

#include "kscfg/base/error.hpp"
#include "kscfg/link/slcan.hpp"

namespace kscfg {

namespace {

constexpr unsigned kRates[] = {10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000};

std::string shown(std::string_view line) {
  std::string s(line.substr(0, 40));
  for (char& c : s)
    if (!std::isprint(static_cast<unsigned char>(c))) c = '?';
  return line.size() > 40 ? s + "..." : s;
}

bool all_hex(std::string_view s) {
  for (char c : s)
    if (!std::isxdigit(static_cast<unsigned char>(c))) return false;
  return true;
}

using Result = SlcanAdapter::Result;

Result taken(std::string what, std::string reply = "\r") {
  Result r;
  r.what = std::move(what);
  r.reply = std::move(reply);
  return r;
}

Result refused(std::string_view line, std::string what) {
  Result r;
  r.what = fmt::format("'{}' refused: {}", shown(line), what);
  r.reply = "\a";
  r.refused = true;
  return r;
}

// t, T, r, R: a frame the host sends, on the bus when the channel is open at the bus's rate.
Result send_frame(const SlcanAdapter& a, std::string_view line, bool listen_only, const SlcanAdapter::Options& opt) {
  if (!a.is_open()) return refused(line, "the channel is closed");
  if (listen_only) return refused(line, "the channel is open listen-only");
  std::optional<CanFrame> f;
  try {
    f = slcan::decode(line);
  } catch (const Error&) {
    return refused(line, "not a frame");
  }
  if (!f) return refused(line, "not a frame");
  if (line.size() != (f->extended ? 10u : 5u) + (f->rtr ? 0u : 2u * f->len))
    return refused(line, "a time stamp is for received frames");
  Result r;
  r.what = fmt::format("sent {}", format_frame(*f));
  if (a.on_bus()) r.frame = f;
  else r.what += fmt::format(" (at {} bit/s on a {} bit/s bus: nobody hears it)", a.bitrate(), opt.bitrate);
  r.reply = opt.ack ? (f->extended ? "Z\r" : "z\r") : "\r";
  return r;
}

}  // namespace

SlcanAdapter::Result SlcanAdapter::command(std::string_view line) {
  auto ok = [](std::string what, std::string reply = "\r") { return taken(std::move(what), std::move(reply)); };
  auto refuse = [&](std::string what) { return refused(line, std::move(what)); };
  if (line.empty()) return ok("empty line");
  char k = line[0];
  std::string_view arg = line.substr(1);
  switch (k) {
    case 'C':
      if (!arg.empty()) return refuse("C takes no argument");
      open_ = false;
      return ok("channel closed");
    case 'O':
    case 'L':
      if (!arg.empty()) return refuse(fmt::format("{} takes no argument", k));
      if (open_) return refuse("the channel is open already");
      open_ = true;
      listen_only_ = k == 'L';
      return ok(fmt::format("channel open{} at {} bit/s{}", listen_only_ ? " (listen only)" : "", bitrate_,
                            on_bus() ? "" : fmt::format(": the bus runs at {}, nothing is heard", opt_.bitrate)));
    case 'S':
      if (open_) return refuse("close the channel first");
      if (arg.size() != 1 || arg[0] < '0' || arg[0] > '8') return refuse("S takes a digit 0..8");
      bitrate_ = kRates[arg[0] - '0'];
      return ok(fmt::format("bit rate {}", bitrate_));
    case 's':
      if (open_) return refuse("close the channel first");
      if (arg.size() != 4 || !all_hex(arg)) return refuse("s takes 4 hex digits");
      bitrate_ = 0;  // bit-timing registers: not one of the bus's rates here
      return ok("bit-timing registers set");
    case 'V': return arg.empty() ? ok("version", "V1013\r") : refuse("V takes no argument");
    case 'v': return arg.empty() ? ok("version", "v1013\r") : refuse("v takes no argument");
    case 'N': return arg.empty() ? ok("serial number", "NKSCF\r") : refuse("N takes no argument");
    case 'F':
      if (!arg.empty()) return refuse("F takes no argument");
      if (!open_) return refuse("the channel is closed");
      return ok("status flags", "F00\r");
    case 'Z':
      if (arg != "0" && arg != "1") return refuse("Z takes 0 or 1");
      timestamps_ = arg == "1";
      return ok(timestamps_ ? "time stamps on" : "time stamps off");
    case 'M':
    case 'm':
      if (arg.size() != 8 || !all_hex(arg)) return refuse(fmt::format("{} takes 8 hex digits", k));
      return ok("acceptance filter taken (not applied)");
    case 'X':
    case 'W':
    case 'Q':
      if (arg.size() > 1) return refuse(fmt::format("{} takes one digit", k));
      return ok(fmt::format("'{}' taken", shown(line)));
    case 't':
    case 'T':
    case 'r':
    case 'R': return send_frame(*this, line, listen_only_, opt_);
    default: return refuse("unknown command");
  }
}

std::string SlcanAdapter::received(const CanFrame& f, std::chrono::steady_clock::time_point now) const {
  if (!on_bus()) return "";
  std::string s = slcan::encode(f);
  if (timestamps_) {
    auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 60000;
    s.insert(s.size() - 1, fmt::format("{:04X}", static_cast<unsigned>(ms)));
  }
  return s;
}

}  // namespace kscfg
