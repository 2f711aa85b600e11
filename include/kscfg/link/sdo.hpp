// The CANopen SDO client of the CANopen link (CiA 301 "SDO protocols"): expedited
// download (1..4 bytes), expedited and segmented upload, one transfer at a time per server, as the
// protocol allows (the default SDO channel of a node has one transfer in progress at a time).
//   client -> server  COB-ID 0x600 + node;  server -> client  COB-ID 0x580 + node
//   byte 0: command specifier; bytes 1..2: index (little endian); byte 3: sub-index; bytes 4..7: data
//   download request 0x23/0x27/0x2B/0x2F (4/3/2/1 bytes, size indicated), answer 0x60
//   upload request 0x40; answer 0x43/0x47/0x4B/0x4F (4/3/2/1 bytes), 0x42 (expedited, size not
//   indicated: 4 bytes), 0x41 (segmented, size in bytes 4..7); then segments 0x60/0x70 (toggle)
//   answered 0b000tnnnc (t toggle, n bytes unused of 7, c last)
//   abort 0x80 from either side, bytes 4..7 the abort code (sdo::abort_text)
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/link/can_frame.hpp"

namespace kscfg {

namespace sdo {
constexpr std::uint32_t kRequestBase = 0x600;    // + node: client to server
constexpr std::uint32_t kReplyBase = 0x580;      // + node: server to client
constexpr std::uint32_t kEmergencyBase = 0x80;   // + node: EMCY (ignored by the client, traced)
constexpr std::uint32_t kHeartbeatBase = 0x700;  // + node: NMT error control (boot-up: one byte 0x00)

// The CiA 301 text of an abort code ("Object does not exist in the object dictionary"), or
// "abort code 0x...." for a code it does not list.
std::string abort_text(std::uint32_t code);

// The request frames (golden vectors: "Id=0x603 DLC=8; Data=23 01 45 05 35 12 1F 80").
CanFrame download_request(unsigned node, std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data);
CanFrame upload_request(unsigned node, std::uint16_t index, std::uint8_t sub);
CanFrame abort_request(unsigned node, std::uint16_t index, std::uint8_t sub, std::uint32_t code);
}  // namespace sdo

// An SDO transfer the server aborted: Error(Exit::refused) whose message names the object and the
// abort text, keeping the code (as a Modbus exception keeps its code).
class SdoAbort : public Error {
 public:
  SdoAbort(std::uint16_t index, std::uint8_t sub, std::uint32_t code, std::string message)
      : Error(Exit::refused, std::move(message)), index_(index), sub_(sub), code_(code) {}
  std::uint16_t index() const noexcept { return index_; }
  std::uint8_t sub() const noexcept { return sub_; }
  std::uint32_t code() const noexcept { return code_; }

 private:
  std::uint16_t index_;
  std::uint8_t sub_;
  std::uint32_t code_;
};

struct SdoOptions {
  unsigned node = 1;                              // CANopen node id 1..127
  unsigned response_timeout_ms = 1000;            // each SDO frame's answer (the server's side: CiA 301 leaves it open)
  std::function<void(const std::string&)> trace;  // -v: frames and retries
};

class SdoClient {
 public:
  SdoClient(CanBus& bus, SdoOptions opt);
  // The object's bytes (expedited or segmented upload). Error(Exit::link) naming the node and bus
  // when the node does not answer a frame within response_timeout_ms (an abort frame 0x05040000
  // "SDO protocol timed out" is sent to it; a silent node is a dead link, not a terminal that did
  // not acknowledge); SdoAbort when it aborts; Error(Exit::link) for an answer that breaks the
  // protocol (another index/sub-index, a bad toggle: an abort is sent) and for a bus that is gone.
  // Frames of other ids are ignored (EMCY and boot-up traced); frames that came in before the
  // request are dropped (a late answer to a request that timed out).
  std::vector<std::uint8_t> upload(std::uint16_t index, std::uint8_t sub);
  // Writes 1..4 bytes (expedited download); errors as upload(). A lost answer is not repeated: the
  // outcome is unknown and the caller reads back.
  void download(std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data);
  std::uint32_t upload_u32(std::uint16_t index, std::uint8_t sub);  // 1..4 bytes, little endian
  void download_u32(std::uint16_t index, std::uint8_t sub, std::uint32_t value);

  unsigned node() const { return opt_.node; }
  CanBus& bus() { return bus_; }
  // SDO requests sent so far (one per expedited transfer; a segmented upload counts each segment).
  std::size_t exchanges() const { return exchanges_; }
  // Two requests in a row got no answer: every later request fails with Error(Exit::link) before
  // anything is sent (a dead bus is given up within two timeouts).
  bool proven_dead() const { return silent_ >= 2; }
  // A request of this run got no answer: why ("node 3 on ... stopped answering (SDO ...)"), "" while
  // every request was answered. No register is written to the node after that in this run
  // (canreg::Registers::write): a write sent meanwhile took effect when the node came back, after
  // the change it belonged to had been given up.
  const std::string& stopped_answering() const { return stopped_; }
  // Before a register access begins: the answer still owed to a request whose wait was cut short
  // (Ctrl-C while the node worked on it) is waited for until that request's deadline and dropped,
  // so that the access's own deadline starts after it (a rollback gets its own deadline).
  void settle() { settle_owed(); }
  // Waits until `t` (bounded, cancellable through the bus), the frames that come meanwhile dropped
  // as before a request: the pause between two uploads of a register read (link/can_registers.hpp).
  void pause_until(std::chrono::steady_clock::time_point t);

 private:
  std::string where() const;  // "node 3 on slcan:/dev/ttyACM0 at 500000 bit/s"
  void trace(const std::string& line) const;
  void drain();
  void send_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept;
  // Sends `req` and waits for the node's answer (response_timeout_ms).
  CanFrame exchange(const CanFrame& req, std::uint16_t index, std::uint8_t sub, const char* what);
  // An abort (SdoAbort) or an answer for another object (Error(link)).
  void check_answer(const CanFrame& f, std::uint16_t index, std::uint8_t sub, const char* what);
  [[noreturn]] void protocol_error(const CanFrame& f, std::uint16_t index, std::uint8_t sub, const char* what,
                                   const std::string& why, std::uint32_t abort_code);
  // Before a request goes out: the answer still owed to one whose wait was cut short (Ctrl-C while the
  // node worked on it) is waited for until that request's deadline and dropped, so that it is not
  // taken for the answer to the next one (SDO answers carry no transaction number).
  void settle_owed();
  CanBus& bus_;
  SdoOptions opt_;
  std::optional<std::chrono::steady_clock::time_point> owed_;  // the deadline of an answer still owed
  std::size_t exchanges_ = 0;
  unsigned silent_ = 0;
  std::string stopped_;  // stopped_answering()
};

}  // namespace kscfg
