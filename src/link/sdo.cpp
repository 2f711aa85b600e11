// The CANopen SDO client (link/sdo.hpp; CiA 301 "SDO protocols").
#include "kscfg/link/sdo.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace kscfg {

namespace sdo {

namespace {
// Command specifiers (byte 0, bits 5..7) and the bits below them.
constexpr std::uint8_t kCsMask = 0xE0;
constexpr std::uint8_t kUploadInitiateAnswer = 0x40;    // scs 2
constexpr std::uint8_t kDownloadInitiateAnswer = 0x60;  // scs 3
constexpr std::uint8_t kUploadSegmentAnswer = 0x00;     // scs 0
constexpr std::uint8_t kAbort = 0x80;                   // cs 4
constexpr std::uint8_t kUploadSegmentRequest = 0x60;    // ccs 3
constexpr std::uint8_t kToggle = 0x10;
}  // namespace

std::string abort_text(std::uint32_t code) {
  struct Known {
    std::uint32_t code;
    const char* text;
  };
  static constexpr Known known[] = {
      {0x05030000, "Toggle bit not alternated"},
      {0x05040000, "SDO protocol timed out"},
      {0x05040001, "Client/server command specifier not valid or unknown"},
      {0x05040002, "Invalid block size"},
      {0x05040003, "Invalid sequence number"},
      {0x05040004, "CRC error"},
      {0x05040005, "Out of memory"},
      {0x06010000, "Unsupported access to an object"},
      {0x06010001, "Attempt to read a write only object"},
      {0x06010002, "Attempt to write a read only object"},
      {0x06020000, "Object does not exist in the object dictionary"},
      {0x06040041, "Object cannot be mapped to the PDO"},
      {0x06040042, "The number and length of the objects to be mapped would exceed PDO length"},
      {0x06040043, "General parameter incompatibility reason"},
      {0x06040047, "General internal incompatibility in the device"},
      {0x06060000, "Access failed due to a hardware error"},
      {0x06070010, "Data type does not match, length of service parameter does not match"},
      {0x06070012, "Data type does not match, length of service parameter too high"},
      {0x06070013, "Data type does not match, length of service parameter too low"},
      {0x06090011, "Sub-index does not exist"},
      {0x06090030, "Invalid value for parameter"},
      {0x06090031, "Value of parameter written too high"},
      {0x06090032, "Value of parameter written too low"},
      {0x06090036, "Maximum value is less than minimum value"},
      {0x060A0023, "Resource not available: SDO connection"},
      {0x08000000, "General error"},
      {0x08000020, "Data cannot be transferred or stored to the application"},
      {0x08000021, "Data cannot be transferred or stored to the application because of local control"},
      {0x08000022, "Data cannot be transferred or stored to the application because of the present device state"},
      {0x08000023, "Object dictionary dynamic generation fails or no object dictionary is present"},
      {0x08000024, "No data available"},
      // Beckhoff's codes for register communication through 0x4500/0x4501 (CX8050, EL6751 manuals).
      {0x06020011, "Invalid table: table or channel not present"},
      {0x06020010, "Invalid register: table not present"},
      {0x06010022, "Write protection still set"},
      {0x06070043, "Incorrect number of function arguments"},
      {0x06010021, "Function still active, try again later"},
      {0x05040040, "General routing error"},
      {0x06060021, "Error accessing BC table"},
      {0x06090010, "General error communicating with terminal"},
      {0x05040047, "Time-out communicating with terminal"},
  };
  for (const auto& k : known)
    if (k.code == code) return k.text;
  return fmt::format("abort code 0x{:08X}", code);
}

namespace {
CanFrame request(unsigned node, std::uint8_t cs, std::uint16_t index, std::uint8_t sub) {
  CanFrame f;
  f.id = kRequestBase + node;
  f.len = 8;
  f.data[0] = cs;
  f.data[1] = static_cast<std::uint8_t>(index & 0xFF);
  f.data[2] = static_cast<std::uint8_t>(index >> 8);
  f.data[3] = sub;
  return f;
}
}  // namespace

CanFrame download_request(unsigned node, std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data) {
  if (data.empty() || data.size() > 4)
    throw Error(Exit::internal, fmt::format("SDO expedited download of {} bytes (1..4)", data.size()));
  auto unused = static_cast<std::uint8_t>(4 - data.size());
  CanFrame f = request(node, static_cast<std::uint8_t>(0x23 | (unused << 2)), index, sub);
  std::copy(data.begin(), data.end(), f.data.begin() + 4);
  return f;
}

CanFrame upload_request(unsigned node, std::uint16_t index, std::uint8_t sub) {
  return request(node, 0x40, index, sub);
}

CanFrame abort_request(unsigned node, std::uint16_t index, std::uint8_t sub, std::uint32_t code) {
  CanFrame f = request(node, kAbort, index, sub);
  for (unsigned k = 0; k < 4; ++k) f.data[4 + k] = static_cast<std::uint8_t>(code >> (8 * k));
  return f;
}

}  // namespace sdo

namespace {

constexpr std::size_t kMaxUpload = 4096;  // a longer object is not one kscfg reads (names, versions)

std::uint32_t le32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

std::string object_name(std::uint16_t index, std::uint8_t sub) { return fmt::format("0x{:04X} sub {}", index, sub); }

}  // namespace

SdoClient::SdoClient(CanBus& bus, SdoOptions opt) : bus_(bus), opt_(std::move(opt)) {
  if (opt_.node < 1 || opt_.node > 127)
    throw Error(Exit::usage, fmt::format("CANopen node id {} is outside 1..127", opt_.node));
}

std::string SdoClient::where() const { return fmt::format("node {} on {}", opt_.node, bus_.describe()); }

void SdoClient::trace(const std::string& line) const {
  if (opt_.trace) opt_.trace("sdo: " + line);
}

// Frames that came in since the last transfer (a late answer to a request that timed out, a
// heartbeat) are not answers to the next one: dropped before it goes out.
void SdoClient::drain() {
  const std::uint32_t reply_id = sdo::kReplyBase + opt_.node;
  while (auto f = bus_.receive(std::chrono::steady_clock::now())) {
    trace("dropped " + format_frame(*f));
    // The answer still owed (settle_owed) has come and gone: nothing more to wait for.
    if (!f->extended && !f->rtr && f->id == reply_id) owed_.reset();
  }
}

void SdoClient::pause_until(std::chrono::steady_clock::time_point t) {
  const std::uint32_t reply_id = sdo::kReplyBase + opt_.node;
  while (auto f = bus_.receive(t)) {
    bool ours = !f->extended && !f->rtr && f->id == reply_id;
    trace("dropped " + format_frame(*f));
    if (ours) owed_.reset();
  }
}

void SdoClient::settle_owed() {
  if (!owed_) return;
  auto deadline = *owed_;
  owed_.reset();
  const std::uint32_t reply_id = sdo::kReplyBase + opt_.node;
  while (auto f = bus_.receive(deadline)) {
    bool ours = !f->extended && !f->rtr && f->id == reply_id;
    trace(std::string(ours ? "dropped the late answer " : "dropped ") + format_frame(*f));
    if (ours) return;
  }
}

void SdoClient::send_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept {
  try {
    CanFrame f = sdo::abort_request(opt_.node, index, sub, code);
    trace(fmt::format("-> {} (abort: {})", format_frame(f), sdo::abort_text(code)));
    bus_.send(f);
  } catch (...) {
    // The bus is gone or the run cancelled: the error of the transfer is what is reported.
  }
}

CanFrame SdoClient::exchange(const CanFrame& req, std::uint16_t index, std::uint8_t sub, const char* what) {
  if (proven_dead())
    throw Error(
        Exit::link,
        fmt::format("{} is given up: two SDO requests in a row got no answer (the bus or the node is dead)", where()),
        "check the CAN wiring, the node id (?node=), the bit rate and the coupler's power");
  settle_owed();
  const std::uint32_t reply_id = sdo::kReplyBase + opt_.node;
  auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(opt_.response_timeout_ms);
  // The answer is owed once the frame went out, until it is taken or the wait ends: a wait cut short
  // by cancellation leaves it owed. A send cut by cancellation wrote nothing (CanBus::send): nothing
  // is owed then, and the trace does not show the frame (before, it was traced and its answer
  // waited for). A send that failed otherwise may have written it.
  try {
    bus_.send(req);
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) {
      trace("not sent (interrupted): " + format_frame(req));
      throw;
    }
    owed_ = deadline;
    throw;
  }
  owed_ = deadline;
  trace("-> " + format_frame(req));
  ++exchanges_;
  for (;;) {
    std::optional<CanFrame> f = bus_.receive(deadline);
    if (!f) break;
    if (f->extended || f->rtr || f->id != reply_id || f->len != 8) {
      if (!f->extended && f->id == sdo::kEmergencyBase + opt_.node && f->id != sdo::kEmergencyBase)
        trace("EMCY " + format_frame(*f));
      else if (!f->extended && f->id == sdo::kHeartbeatBase + opt_.node && f->len == 1 && f->data[0] == 0)
        trace("boot-up " + format_frame(*f) + " (the node restarted)");
      else if (opt_.trace) trace("ignored " + format_frame(*f));
      continue;
    }
    trace("<- " + format_frame(*f));
    silent_ = 0;
    owed_.reset();
    return *f;
  }
  owed_.reset();
  ++silent_;
  if (stopped_.empty())
    stopped_ = fmt::format("{} stopped answering (SDO {} {} got no answer within {} ms)", where(), what,
                           object_name(index, sub), opt_.response_timeout_ms);
  send_abort(index, sub, 0x05040000);
  throw Error(Exit::link,
              fmt::format("{} did not answer SDO {} {} within {} ms", where(), what, object_name(index, sub),
                          opt_.response_timeout_ms),
              "check the CAN wiring, the node id (?node=), the bit rate and the coupler's power");
}

void SdoClient::check_answer(const CanFrame& f, std::uint16_t index, std::uint8_t sub, const char* what) {
  std::uint16_t got_index = static_cast<std::uint16_t>(f.data[1] | (f.data[2] << 8));
  std::uint8_t got_sub = f.data[3];
  if (f.data[0] == sdo::kAbort) {
    if (got_index != index || got_sub != sub)
      throw Error(Exit::link, fmt::format("{} aborted SDO {} {} naming another object, {}", where(), what,
                                          object_name(index, sub), object_name(got_index, got_sub)));
    std::uint32_t code = le32(&f.data[4]);
    throw SdoAbort(index, sub, code,
                   fmt::format("{} aborted SDO {} {}: {} (0x{:08X})", where(), what, object_name(index, sub),
                               sdo::abort_text(code), code));
  }
  if (got_index != index || got_sub != sub) {
    send_abort(index, sub, 0x08000000);
    throw Error(Exit::link, fmt::format("{} answered SDO {} {} for another object, {} ({})", where(), what,
                                        object_name(index, sub), object_name(got_index, got_sub), format_frame(f)));
  }
}

[[noreturn]] void SdoClient::protocol_error(const CanFrame& f, std::uint16_t index, std::uint8_t sub, const char* what,
                                            const std::string& why, std::uint32_t abort_code) {
  send_abort(index, sub, abort_code);
  throw Error(Exit::link, fmt::format("{} broke the SDO protocol in {} {}: {} ({})", where(), what,
                                      object_name(index, sub), why, format_frame(f)));
}

std::vector<std::uint8_t> SdoClient::upload(std::uint16_t index, std::uint8_t sub) {
  drain();
  CanFrame f = exchange(sdo::upload_request(opt_.node, index, sub), index, sub, "upload");
  check_answer(f, index, sub, "upload");
  std::uint8_t cs = f.data[0];
  if ((cs & sdo::kCsMask) != sdo::kUploadInitiateAnswer || (cs & 0x10))
    protocol_error(f, index, sub, "upload", "not an upload answer", 0x05040001);
  const bool expedited = cs & 0x02, sized = cs & 0x01;
  if (expedited) {
    std::size_t n = sized ? 4 - ((cs >> 2) & 0x3) : 4;
    return {f.data.begin() + 4, f.data.begin() + 4 + static_cast<std::ptrdiff_t>(n)};
  }
  // Segmented: the size (when indicated), then segments of up to 7 bytes, the toggle bit
  // alternating from 0, the last one marked.
  std::optional<std::size_t> size;
  if (sized) size = le32(&f.data[4]);
  if (size && *size > kMaxUpload)
    protocol_error(f, index, sub, "upload",
                   fmt::format("{} bytes announced (kscfg reads at most {})", *size, kMaxUpload), 0x05040005);
  std::vector<std::uint8_t> out;
  std::uint8_t toggle = 0;
  for (;;) {
    CanFrame seg = sdo::upload_request(opt_.node, index, sub);
    seg.data = {};
    seg.data[0] = static_cast<std::uint8_t>(sdo::kUploadSegmentRequest | toggle);
    CanFrame a = exchange(seg, index, sub, "upload");
    if (a.data[0] == sdo::kAbort) check_answer(a, index, sub, "upload");
    if ((a.data[0] & sdo::kCsMask) != sdo::kUploadSegmentAnswer)
      protocol_error(a, index, sub, "upload", "not an upload segment", 0x05040001);
    if ((a.data[0] & sdo::kToggle) != toggle)
      protocol_error(a, index, sub, "upload", "the toggle bit did not alternate", 0x05030000);
    std::size_t n = 7 - ((a.data[0] >> 1) & 0x7);
    out.insert(out.end(), a.data.begin() + 1, a.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
    if (out.size() > kMaxUpload)
      protocol_error(a, index, sub, "upload", fmt::format("more than {} bytes", kMaxUpload), 0x05040005);
    if (a.data[0] & 0x01) break;
    toggle ^= sdo::kToggle;
  }
  if (size && out.size() != *size)
    throw Error(Exit::link, fmt::format("{} announced {} bytes of SDO upload {} and sent {}", where(), *size,
                                        object_name(index, sub), out.size()));
  return out;
}

void SdoClient::download(std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data) {
  CanFrame req = sdo::download_request(opt_.node, index, sub, data);
  drain();
  CanFrame f = exchange(req, index, sub, "download");
  check_answer(f, index, sub, "download");
  if (f.data[0] != sdo::kDownloadInitiateAnswer)
    protocol_error(f, index, sub, "download", "not a download answer", 0x05040001);
}

std::uint32_t SdoClient::upload_u32(std::uint16_t index, std::uint8_t sub) {
  auto bytes = upload(index, sub);
  if (bytes.empty() || bytes.size() > 4)
    throw Error(Exit::link, fmt::format("{} answered SDO upload {} with {} bytes (an integer has 1..4)", where(),
                                        object_name(index, sub), bytes.size()));
  std::uint32_t v = 0;
  for (std::size_t k = 0; k < bytes.size(); ++k) v |= static_cast<std::uint32_t>(bytes[k]) << (8 * k);
  return v;
}

void SdoClient::download_u32(std::uint16_t index, std::uint8_t sub, std::uint32_t value) {
  std::uint8_t b[4];
  for (unsigned k = 0; k < 4; ++k) b[k] = static_cast<std::uint8_t>(value >> (8 * k));
  download(index, sub, b);
}

}  // namespace kscfg
