// Modbus couplers (docs/transports/modbus.md): the BK9000/BK7300 register map, Modbus TCP (BK9000
// family) and Modbus RTU over a serial port (BK7300 family) endpoints, and one connection with
// bounded retries.
#pragma once
#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/port_uri.hpp"

typedef struct _modbus modbus_t;

namespace kscfg {

// The BK9000/BK7300 register map.
namespace mbmap {
constexpr std::uint16_t kInputImage = 0x0000;   // input image, 256 registers (FC3/FC4/FC23 read)
constexpr std::uint16_t kOutputImage = 0x0800;  // output image, 256 registers (FC3 read; FC6/FC16/FC23 write)
constexpr unsigned kImageRegisters = 0x100;
constexpr std::uint16_t kIdent = 0x1000;  // 7 registers, 14 ASCII characters
constexpr unsigned kIdentRegisters = 7;
constexpr std::uint16_t kCouplerStatus = 0x100A;   // 0x100A..0x100C: PLC interface, terminal diagnosis, coupler status
constexpr std::uint16_t kImageLengths = 0x1010;    // bits: complex out, complex in, digital out, digital in
constexpr std::uint16_t kWatchdogTime = 0x1020;    // ms since the watchdog was last retriggered
constexpr std::uint16_t kWatchdogPreset = 0x1120;  // ms, default 1000, 0 = off
constexpr std::uint16_t kWatchdogReset = 0x1121;   // write 0xBECF then 0xAFFE
constexpr std::uint16_t kWatchdogType =
    0x1122;  // BK9000: 1 = telegram watchdog (default); BK7300: 0 = write telegram (default)
constexpr unsigned kMaxRead = 125, kMaxWrite = 123, kMaxWriteRead = 121;

// Identification: 14 ASCII characters, the first character in the LOW byte of 0x1000 (as public
// BK9000 drivers decode it). The emulator puts the coupler name there, padded with spaces.
std::array<std::uint16_t, kIdentRegisters> encode_ident(const std::string& text);
// No manual says how the characters sit in the registers, so every plausible way is tried: two
// per register (low byte first, or high byte first) or one per register (in the low or the high
// byte). The first decoding that starts with a known coupler name wins, then the first that is
// all printable ASCII; NUL padding and trailing spaces are dropped, other bytes shown as '?'.
std::string decode_ident(std::span<const std::uint16_t> regs);
// The same registers read the other way (high byte first when decode_ident took the low byte
// first, and so on); "" when that gives no printable text. For an identification kscfg does not
// recognise, so a user can read it either way.
std::string decode_ident_other(std::span<const std::uint16_t> regs);

// "slave device busy" for 6; "unknown exception" otherwise.
std::string exception_name(int code);
}  // namespace mbmap

// A Modbus endpoint from a port URI (tcp://HOST[:PORT][?unit=N], rtu:DEVICE[?baud=&parity=&data=&stop=&unit=]).
struct ModbusTarget {
  std::string uri;
  bool tcp = true;
  std::string host;
  unsigned port = 502;
  std::string device;
  unsigned baud = 19200;
  char parity = 'E';  // Modbus RTU default 8E1; pseudo-terminals need N
  unsigned data_bits = 8;
  unsigned stop_bits = 1;
  int unit = 1;
  std::string where() const;  // "127.0.0.1:502 unit 1" / "/dev/ttyUSB0 unit 1"
};
// Checks every value strictly; Error(Exit::usage) for bad ones.
ModbusTarget modbus_target(const PortUri& p, const std::string& uri);

// Serial line settings applied one by one so that a refused setting is named in the error.
// Returns an open, exclusively locked file descriptor in raw mode. Error(Exit::link) with a hint
// for: no such device, permission denied (dialout), busy, not a tty, a setting the device refuses.
int open_serial(const std::string& device, unsigned baud, char parity, unsigned data_bits, unsigned stop_bits);

struct ModbusOptions {
  unsigned response_timeout_ms = 500;  // one request/response
  unsigned connect_timeout_ms = 1000;
  unsigned retries = 3;  // extra attempts after CRC errors or garbled replies
  // A coupler that answers busy (exception 6) is tried again for this long (0: response_timeout_ms),
  // busy::pause() apart (link/busy.hpp); a connection closed after a busy answer counts as busy.
  unsigned busy_wait_ms = 0;
  unsigned timeout_retries = 1;  // extra attempts after a timeout
  unsigned poll_us = 500;        // between two polls of the input image (ModbusLink::poll_gap())
  std::function<void(const std::string&)> trace;
  // The run's cancellation (base/cancel.hpp): a request or the wait for its reply ends with
  // Error(Exit::interrupted) once it is cancelled. Null: never cancelled.
  const CancelToken* cancel = nullptr;
};

// A Modbus coupler's registers beyond its process image (identification 0x1000.., image lengths
// 0x1010.., watchdog 0x1120..): what the Modbus port and its scan read of a Modbus coupler. The
// ModbusClient of a ModbusLink is one.
class ModbusRegisters {
 public:
  virtual ~ModbusRegisters() = default;
  virtual std::vector<std::uint16_t> read(std::uint16_t addr, unsigned count) = 0;
  // As read(), but a register the coupler does not serve (exception 2, illegal data address) is
  // not an error: std::nullopt. For optional registers (docs/transports/modbus.md).
  virtual std::optional<std::vector<std::uint16_t>> read_optional(std::uint16_t addr, unsigned count) = 0;
  virtual const ModbusTarget& target() const = 0;
};

// One Modbus connection with bounded retries; every failure is an Error(Exit::link) in one line.
class ModbusClient : public ModbusRegisters {
 public:
  ModbusClient(ModbusTarget target, ModbusOptions opt);
  ~ModbusClient() override;
  ModbusClient(const ModbusClient&) = delete;
  ModbusClient& operator=(const ModbusClient&) = delete;

  std::vector<std::uint16_t> read(std::uint16_t addr, unsigned count) override;
  std::optional<std::vector<std::uint16_t>> read_optional(std::uint16_t addr, unsigned count) override;
  void write(std::uint16_t addr, std::span<const std::uint16_t> values);
  // FC23: writes first, then reads, in one exchange.
  std::vector<std::uint16_t> write_read(std::uint16_t waddr, std::span<const std::uint16_t> values, std::uint16_t raddr,
                                        unsigned count);

  // A link proven dead: two requests in a row got no answer after all their attempts (each about
  // the ack timeout). From then on every request fails at once with that reason, so that a
  // rollback or a restore over a dead link ends within about two timeouts
  // instead of trying every register for seconds. Empty while the link lives.
  const std::string& dead() const { return dead_; }

  const ModbusTarget& target() const override { return target_; }
  const ModbusOptions& options() const { return opt_; }
  std::size_t exchanges() const { return exchanges_; }  // requests sent, retries included
  std::size_t retried() const { return retried_; }

 private:
  void connect();
  void disconnect();
  bool cancelled() const { return opt_.cancel && opt_.cancel->cancelled(); }
  // RTU, after a timeout: reads and drops a late reply before the next request goes out.
  void drain_late_reply();
  // Runs one request with bounded retries. `addr`/`count`: the registers it reads or writes (for
  // the hint of an exception 2). With `refused`, exception 2 sets it and returns instead of throwing.
  // With `parse` (the expected reply from its raw bytes), the wait for a reply is cut into slices
  // of kSlice: between two, cancellation (ModbusOptions::cancel) ends it.
  template <class F, class P>
  void run(const std::string& what, std::uint16_t addr, unsigned count, F&& f, P&& parse, bool* refused = nullptr);
  // The retry state of one request.
  struct Attempts {
    unsigned timeouts = 0, others = 0, busy_tries = 0;
    bool busy = false;  // an attempt was answered "busy" (exception 6)
    std::optional<std::chrono::steady_clock::time_point> busy_since;
  };
  // One attempt of a request (`sent`: when it went out). Returns f's result: >= 0, or -1 with errno.
  template <class F, class P>
  int attempt(F&& f, P&& parse, std::chrono::steady_clock::time_point& sent);
  // The retry policy, for an attempt that failed with errno `e`: true to try again (after what
  // that takes: a fresh connection, a drained line, a busy pause), false when `refused` was set;
  // throws when the request is given up.
  bool try_again(const std::string& what, std::uint16_t addr, unsigned count, int e, Attempts& a, bool* refused);
  void wait_while_busy(const std::string& what, int e, Attempts& a);  // busy: a pause, or throws
  [[noreturn]] void interrupted(const std::string& what, std::chrono::steady_clock::time_point sent, const Attempts& a);
  // After the first slice passed without a reply: waits on for it (modbus_receive_confirmation)
  // until the response timeout, slice by slice. Returns f's result: >= 0, or -1 with errno.
  template <class P>
  int wait_reply(std::chrono::steady_clock::time_point sent, P&& parse);
  void set_response_timeout(std::chrono::microseconds t);

  ModbusTarget target_;
  ModbusOptions opt_;
  modbus_t* ctx_ = nullptr;
  int serial_fd_ = -1;
  std::size_t exchanges_ = 0, retried_ = 0;
  unsigned silent_ = 0;          // requests in a row that failed without any answer
  std::string dead_;             // why the link is taken for dead ("" while it lives)
  bool drain_ = false;           // RTU: a reply may still come for a request given up on (interrupted)
  bool connected_once_ = false;  // a connect() succeeded: a later refusal means the coupler went away
  std::string broke_;            // why the connection was dropped last (a reset, ...), for that message
};

}  // namespace kscfg
