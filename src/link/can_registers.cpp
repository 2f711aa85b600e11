// Bus Terminal register communication over CANopen SDO (link/can_registers.hpp).
#include "kscfg/link/can_registers.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "kscfg/link/ads_registers.hpp"

namespace kscfg::canreg {

// ---- The wire procedure, in one place (docs/design.md section 13; BK51x0/CX8050 manuals, "Bus ----
// ---- Coupler / Bus Terminal register communication") --------------------------------------------
namespace {
// 0x4500 is read and written at sub-index 0 (the table is in byte 3 of the word).
constexpr std::uint8_t kCouplerSub = 0;
// "Function still active, try again later": the coupler is still busy with the previous access
// (a write carries on after its download answer); the access is asked again until the timeout.
constexpr std::uint32_t kStillActive = 0x06010021;
// WRITE: download the word with the access bit set; the download answer means done (no completion
// poll is documented, and the stored access bit stays 1). The safety rules read it back.
// READ: download the address with the access bit clear, then upload the same entry; "the coupler
// sets the access bit to 1 until the correct value is available": uploaded again while it reads 1.
// The answer echoes channel (or table) and register: another one breaks the protocol.
Word request_word(bool write, unsigned group, unsigned reg, std::uint16_t value) {
  return Word{write, group, reg, write ? value : std::uint16_t{0}};
}
bool value_available(const Word& got) { return !got.access; }
bool echoes(const Word& got, unsigned group, unsigned reg) { return got.group == group && got.reg == reg; }
}  // namespace

// PROVISIONAL (medium confidence, design 13): sub-index N counts every terminal the coupler sees on
// the K-bus, digital ones too, not passive ones: the numbering of ADS port 100.
unsigned terminal_number(const StationLayout& layout, unsigned position) {
  return adsreg::terminal_number(layout, position);
}
// -------------------------------------------------------------------------------------------------

std::uint32_t encode(const Word& w) {
  return (w.access ? kAccessBit : 0u) | (static_cast<std::uint32_t>(w.group & 0x7F) << 24) |
         (static_cast<std::uint32_t>(w.reg & 0xFF) << 16) | w.value;
}

Word decode(std::uint32_t v) {
  Word w;
  w.access = (v & kAccessBit) != 0;
  w.group = (v >> 24) & 0x7F;
  w.reg = (v >> 16) & 0xFF;
  w.value = static_cast<std::uint16_t>(v & 0xFFFF);
  return w;
}

unsigned max_uploads(unsigned timeout_ms) {
  // The paced ones went at the earliest kMaxUploads x 250 us after the download.
  double t = 0.25 * (kMaxUploads - 1), end = timeout_ms;
  unsigned n = kMaxUploads;
  while (t < end) {
    t += std::max(0.25, t / 4);
    ++n;
  }
  return n;
}

Registers::Registers(SdoClient& sdo, unsigned timeout_ms) : sdo_(sdo), timeout_ms_(timeout_ms) {}

namespace {

// Runs `access` again while the coupler aborts it with "function still active" and the deadline has
// not passed.
template <class F>
auto again_while_active(std::chrono::steady_clock::time_point deadline, F&& access) {
  for (;;) {
    try {
      return access();
    } catch (const SdoAbort& a) {
      if (a.code() != kStillActive || std::chrono::steady_clock::now() >= deadline) throw;
    }
  }
}

constexpr std::chrono::microseconds kShortestPause{200};

// The uploads without a pacing of the session's: the first at once (a coupler table is the
// coupler's own memory), the next ones every eighth of the time since the download, at least 250 us
// apart.
class DefaultPacing final : public UploadPacing {
 public:
  std::chrono::microseconds next(unsigned n, std::chrono::microseconds last) override {
    if (n == 1) return std::chrono::microseconds(0);
    return last + std::max(std::chrono::microseconds(250), last / 8);
  }
  void seen(unsigned, std::chrono::microseconds, std::chrono::microseconds) override {}
  void early() override {}
};

// One register request on `index` sub `sub`, bounded overall by `timeout_ms`. `what` names the
// register in errors ("terminal 5 channel 1 R31"); an abort is rethrown naming it.
std::uint16_t run(SdoClient& sdo, unsigned timeout_ms, std::uint16_t index, std::uint8_t sub, bool write,
                  unsigned group, unsigned reg, std::uint16_t value, const std::string& what, UploadPacing* pacing) {
  using Clock = std::chrono::steady_clock;
  using std::chrono::microseconds;
  if (group > 0x7F || reg > 0xFF)
    throw Error(Exit::usage,
                fmt::format("{}: outside the register word (channel/table 0..127, register 0..255)", what));
  if (write && !sdo.stopped_answering().empty())
    throw Error(Exit::link, fmt::format("{}: not written: {} in this run", what, sdo.stopped_answering()),
                "check the CAN wiring and the coupler's power, then run the command again");
  // An answer still owed to a request Ctrl-C cut short is waited for first: the deadline is this
  // access's own (a rollback's read was declared timed out after one busy answer).
  sdo.settle();
  auto deadline = Clock::now() + std::chrono::milliseconds(timeout_ms);
  DefaultPacing fallback;
  UploadPacing& pace = pacing ? *pacing : fallback;
  auto us_since = [](Clock::time_point t) { return std::chrono::duration_cast<microseconds>(Clock::now() - t); };
  try {
    Clock::time_point sent;
    again_while_active(deadline, [&] {
      sent = Clock::now();
      sdo.download_u32(index, sub, encode(request_word(write, group, reg, value)));
    });
    if (write) return value;
    microseconds last{0};
    for (unsigned n = 1;; ++n) {
      // Paced for kMaxUploads, then every quarter of the time since the download: bounded whatever
      // the pacing says (at --timeout 1000, at most about 40 uploads a register).
      Clock::time_point planned =
          sent + (n <= kMaxUploads ? pace.next(n, last) : last + std::max(microseconds(250), last / 4));
      if (planned > deadline) planned = deadline;
      // Before the first upload, a pause shorter than a frame's time on the bus (about 240 us at
      // 500 kbit/s) is not slept: a sleep costs more than that on a loaded computer, the upload no
      // more than a frame. The later ones keep their spacing.
      if (n > 1 || planned - Clock::now() > kShortestPause) sdo.pause_until(planned);
      const microseconds late =
          std::max(microseconds(0), std::chrono::duration_cast<microseconds>(Clock::now() - planned));
      last = us_since(sent);
      Word got = decode(again_while_active(deadline, [&] { return sdo.upload_u32(index, sub); }));
      if (value_available(got)) {
        if (!echoes(got, group, reg))
          throw Error(Exit::link, fmt::format("{}: the coupler at node {} answered the read with channel/table {} "
                                              "register {} (0x{:04X} sub {} reads 0x{:08X})",
                                              what, sdo.node(), got.group, got.reg, index, sub, encode(got)));
        pace.seen(n, last, late);
        return got.value;
      }
      if (n == 1) pace.early();
      if (Clock::now() >= deadline)
        throw Error(Exit::timeout,
                    fmt::format("{}: the coupler at node {} did not have the value within {} ms (0x{:04X} sub {} "
                                "reads 0x{:08X}: the access bit stays set)",
                                what, sdo.node(), timeout_ms, index, sub, encode(got)),
                    "the terminal did not answer the coupler: check that it is plugged and powered");
    }
  } catch (const SdoAbort& a) {
    throw SdoAbort(
        a.index(), a.sub(), a.code(),
        fmt::format("{}: the coupler at node {} aborted the {} through 0x{:04X} sub {}: {} (0x{:08X})", what,
                    sdo.node(), write ? "write" : "read", a.index(), a.sub(), sdo::abort_text(a.code()), a.code()));
  }
}

std::string terminal_name(unsigned terminal, unsigned channel, unsigned reg) {
  return fmt::format("terminal {} (0x4501 sub-index {}) channel {} R{}", terminal, terminal, channel + 1, reg);
}

std::uint8_t terminal_sub(unsigned terminal) {
  if (terminal < 1 || terminal > kMaxTerminals)
    throw Error(Exit::usage,
                fmt::format("terminal number {} is outside 1..{} (0x4501 sub-index)", terminal, kMaxTerminals));
  return static_cast<std::uint8_t>(terminal);
}

}  // namespace

std::uint16_t Registers::read(unsigned terminal, unsigned channel, unsigned reg, UploadPacing* pacing) {
  return run(sdo_, timeout_ms_, kTerminalObject, terminal_sub(terminal), false, channel, reg, 0,
             terminal_name(terminal, channel, reg), pacing);
}

void Registers::write(unsigned terminal, unsigned channel, unsigned reg, std::uint16_t value) {
  run(sdo_, timeout_ms_, kTerminalObject, terminal_sub(terminal), true, channel, reg, value,
      terminal_name(terminal, channel, reg), nullptr);
}

std::uint16_t Registers::read_table(unsigned table, unsigned reg) {
  return run(sdo_, timeout_ms_, kCouplerObject, kCouplerSub, false, table, reg, 0,
             fmt::format("coupler table {} register {}", table, reg), nullptr);
}

unsigned Registers::terminal_count() {
  std::uint32_t n = sdo_.upload_u32(kTerminalObject, 0);
  if (n > kMaxTerminals)
    throw Error(Exit::link, fmt::format("node {} reports {} terminals in 0x4501 sub-index 0 (at most {})", sdo_.node(),
                                        n, kMaxTerminals));
  return static_cast<unsigned>(n);
}

}  // namespace kscfg::canreg
