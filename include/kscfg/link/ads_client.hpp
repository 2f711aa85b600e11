// The ADS client: one AMS/TCP connection to a Beckhoff coupler (BK9000 family, BC/BX Bus
// Terminal Controllers) with several requests in flight, matched by invoke id. No router and no
// ReadState: the client talks to the coupler's own AMS/TCP port directly.
//
// Facts it relies on (BK/BC9000 manual, "ADS services",
// https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html): a TCP connection takes 20-30 ms
// to set up, and the coupler cuts one that carried nothing for 10 s. So a run keeps one connection
// and opens it again, transparently, when the coupler has cut it.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg {

// ADS ports of a BK/BC9000 ("ADS protocol", https://infosys.beckhoff.com/content/1033/bc9000/2802214411.html):
// "Port 100: register access; Port 300: fieldbus process data".
namespace adsport {
constexpr std::uint16_t kRegisters = 100;
constexpr std::uint16_t kProcessData = 300;
}  // namespace adsport

// An ADS endpoint from a port URI: ads://HOST[:PORT][?netid=A.B.C.D.E.F&source=A.B.C.D.E.F].
struct AdsTarget {
  std::string uri;
  std::string host;
  unsigned port = ams::kTcpPort;
  std::optional<ams::NetId> netid;   // the coupler's; default: its IP address plus .1.1
  std::optional<ams::NetId> source;  // ours; default: the connection's local address plus .1.1
  std::string where() const;         // "10.0.3.11:48898"
};
// Checks every value strictly; Error(Exit::usage) for bad ones.
AdsTarget ads_target(const PortUri& p, const std::string& uri);

struct AdsOptions {
  unsigned response_timeout_ms = 1000;  // one request, unless the call gives its own
  unsigned connect_timeout_ms = 1000;
  unsigned window = 16;          // requests in flight on the connection at most
  unsigned idle_cut_ms = 10000;  // the coupler closes a connection idle this long
  // A server whose connections are all in use closes (or resets, or refuses) a new one before it
  // answers anything: tried again for this long (0: response_timeout_ms), busy::pause() apart, as a
  // busy Modbus server is (link/busy.hpp).
  unsigned busy_wait_ms = 0;
  std::function<void(const std::string&)> trace;
  // The run's cancellation (base/cancel.hpp): every wait looks at it at least every 50 ms and ends
  // with Error(Exit::interrupted) once it is cancelled. Null: never cancelled.
  const CancelToken* cancel = nullptr;
};

class AdsClient {
 public:
  // The AMS port the client sends from (any port of the client range; a coupler answers to it).
  static constexpr std::uint16_t kSourcePort = 32905;

  struct Call {
    std::uint16_t port = 0;     // target AMS port
    std::uint16_t command = 0;  // ams::kRead, kWrite, kReadWrite, kReadDeviceInfo
    std::vector<std::uint8_t> data;
    // Whether sending it again is harmless when its reply was lost with the connection (reads,
    // image writes). A lost reply to a call that is not repeatable is an error: its outcome is
    // unknown, and the caller has to read back what happened.
    bool repeatable = true;
    unsigned timeout_ms = 0;  // 0: AdsOptions::response_timeout_ms
    std::string what;         // for messages: "reading terminal 3 channel 1 R8"
  };
  struct Reply {
    std::uint32_t result = 0;        // ADS return code (0: done)
    std::vector<std::uint8_t> data;  // Read/ReadWrite: the data; ReadDeviceInfo: version and name
  };

  AdsClient(AdsTarget target, AdsOptions opt);
  ~AdsClient();
  AdsClient(const AdsClient&) = delete;
  AdsClient& operator=(const AdsClient&) = delete;

  // Sends every call, at most `window` in flight, and returns their replies in order. A transport
  // failure, an AMS error in a reply's header or a reply that does not parse throws
  // Error(Exit::link) naming the cause; cancellation (AdsOptions::cancel) throws Error(Exit::interrupted) within
  // 50 ms. An ADS result other than 0 is returned in Reply::result: what it means depends on the call.
  //
  // Every wait is bounded in this one place (docs/transports/ads.md, "Waits over ADS"): a call has its
  // timeout from when it first went out, sent again or not. A connection that goes away with calls
  // outstanding: the repeatable ones go out again on a fresh connection within that deadline, the
  // others fail (their outcome is unknown); a call past its deadline is given up, never sent again,
  // and the message states the time it waited. A server that closes connections before answering
  // (full) is tried again over the busy wait, within the same deadlines. So a batch ends at the
  // latest when its last call's timeout has passed since that call first went out.
  std::vector<Reply> transact(std::span<const Call> calls);
  Reply call(const Call& c);

  // One call each; an ADS result other than 0 throws ads_error().
  std::vector<std::uint8_t> read(std::uint16_t port, std::uint32_t group, std::uint32_t offset, std::uint32_t length,
                                 const std::string& what);
  void write(std::uint16_t port, std::uint32_t group, std::uint32_t offset, std::span<const std::uint8_t> data,
             const std::string& what, bool repeatable = true);
  struct DeviceInfo {
    unsigned major = 0, minor = 0, build = 0;
    std::string name;
  };
  DeviceInfo device_info(std::uint16_t port);

  // The error for ADS result `code` of `what` on `port`: the name and code, and a hint that names
  // the cause (Error(Exit::link); 0x704 and 0x701 are Exit::refused).
  Error ads_error(std::uint32_t code, std::uint16_t port, const std::string& what) const;

  const AdsTarget& target() const { return target_; }
  const AdsOptions& options() const { return opt_; }
  // The NetIds used (known once connected; the URI's when it gives them).
  ams::NetId target_netid();
  ams::NetId source_netid();
  std::size_t exchanges() const { return exchanges_; }  // requests sent, repeats included
  std::size_t connects() const { return connects_; }    // connections opened
  // Replies dropped because no request of the batch waits for their invoke id (a reply that came
  // after its request timed out, a duplicate, a coupler's mistake): counted, never fatal.
  std::size_t strays() const { return strays_; }
  // The dead-link rule, as the Modbus client's (ModbusClient::dead()): two batches in a row given up
  // (a timeout, a connection that could not be made again, a wait cut by cancellation) while the
  // coupler said nothing for a quarter of a second at least, and the link is taken for dead; from
  // then on every call fails at once with this reason, so that a rollback over a stopped coupler
  // ends within two timeouts instead of waiting a timeout per register, and a Ctrl-C during such a
  // stall within one. Empty while the link lives; any answer ends a run of silent batches.
  const std::string& dead() const { return dead_; }

 private:
  struct Pending;
  struct Batch;
  // Connects, trying a refused connection again over the busy wait, each attempt bounded by the
  // connect timeout and by `until` (a call's deadline; default: none).
  void connect(std::chrono::steady_clock::time_point until = std::chrono::steady_clock::time_point::max());
  void connect_once(std::chrono::milliseconds timeout);
  void connected();  // a connection just made: its socket options and the NetIds used on it
  // Runs every call of `b` to its reply: the window filled, the replies taken as they come.
  std::vector<Reply> run_batch(Batch& b);
  // The connection handling of a batch: a fresh connection before the first call goes out on an
  // idle or closed one; one lost with calls outstanding (sent again, or given up).
  void fresh_connection(const Batch& b);
  void connection_lost(Batch& b, const Error& why);
  void fill_window(Batch& b);  // sends calls while the window has room
  // How long to wait for bytes: until the earliest deadline (50 ms at most); throws for a call past it.
  long long wait_within_deadlines(const Batch& b) const;
  void take_frames(Batch& b);  // the complete frames received: the replies they carry
  ams::Header header_for(const Call& c, std::uint32_t invoke) const;
  // A batch given up: counts towards the dead-link rule when nothing was heard while it waited.
  void gave_up(const Batch& b);
  void disconnect();
  bool peer_closed();  // the coupler has closed the connection (an idle cut) while nothing was pending
  void send_all(const std::vector<std::uint8_t>& frame);
  // Waits up to `ms` (at most 50 at a time, checking the cancellation token) for bytes; false: none.
  bool receive(int ms);

  AdsTarget target_;
  AdsOptions opt_;
  int fd_ = -1;
  ams::NetId target_id_{}, source_id_{};
  std::vector<std::uint8_t> in_;
  std::uint32_t next_invoke_ = 1;
  int connect_errno_ = 0;  // why the last connect_once() failed
  bool answered_ = false;  // a frame came on this connection (a full server closes one before any)
  std::chrono::steady_clock::time_point last_activity_{};
  std::chrono::steady_clock::time_point last_heard_{};  // the last frame from the coupler
  unsigned silent_ = 0;                                 // batches in a row given up without an answer
  std::string dead_;                                    // why the link is taken for dead ("" while it lives)
  std::size_t exchanges_ = 0, connects_ = 0, strays_ = 0;
};

}  // namespace kscfg
