// Real links (DESIGN.md section 4): Modbus TCP (BK9000 family) and Modbus RTU over a serial
// port (BK7300 family), the coupler's register map, discovery of the station (scan), the list of
// serial ports, and the Modbus server behind `kscfg serve`.
#pragma once
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/station.hpp"

typedef struct _modbus modbus_t;

namespace kscfg {

// The BK9000/BK7300 register map.
namespace mbmap {
constexpr std::uint16_t kInputImage = 0x0000;   // input image, 256 registers (FC3/FC4/FC23 read)
constexpr std::uint16_t kOutputImage = 0x0800;  // output image, 256 registers (FC3 read; FC6/FC16/FC23 write)
constexpr unsigned kImageRegisters = 0x100;
constexpr std::uint16_t kIdent = 0x1000;  // 7 registers, 14 ASCII characters
constexpr unsigned kIdentRegisters = 7;
constexpr std::uint16_t kCouplerStatus = 0x100A;  // 0x100A..0x100C: PLC interface, terminal diagnosis, coupler status
constexpr std::uint16_t kImageLengths = 0x1010;   // bits: complex out, complex in, digital out, digital in
constexpr std::uint16_t kWatchdogTime = 0x1020;   // ms since the watchdog was last retriggered
constexpr std::uint16_t kWatchdogPreset = 0x1120; // ms, default 1000, 0 = off
constexpr std::uint16_t kWatchdogReset = 0x1121;  // write 0xBECF then 0xAFFE
constexpr std::uint16_t kWatchdogType = 0x1122;   // BK9000: 1 = telegram watchdog (default); BK7300: 0 = write telegram (default)
constexpr unsigned kMaxRead = 125, kMaxWrite = 123, kMaxWriteRead = 121;

// Identification: 14 ASCII characters, the first character in the LOW byte of 0x1000 (as public
// BK9000 drivers decode it). The emulator puts the coupler name there, padded with spaces.
std::array<std::uint16_t, kIdentRegisters> encode_ident(const std::string& text);
std::string decode_ident(std::span<const std::uint16_t> regs);  // trailing spaces/NULs trimmed

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
  unsigned retries = 3;                // extra attempts after busy, CRC or garbled replies
  unsigned timeout_retries = 1;        // extra attempts after a timeout
  // After writing outputs, reads of the input image wait this long: the K-bus needs a cycle to
  // carry the request to the terminal and one to bring the answer back.
  unsigned settle_us = 2500;
  unsigned poll_us = 500;  // between two polls of the input image
  unsigned ack_timeout_ms = 1000;  // the user's --timeout: register sessions of a scan
  std::function<void(const std::string&)> trace;
};

// One Modbus connection with bounded retries; every failure is an Error(Exit::link) in one line.
class ModbusClient {
 public:
  ModbusClient(ModbusTarget target, ModbusOptions opt);
  ~ModbusClient();
  ModbusClient(const ModbusClient&) = delete;
  ModbusClient& operator=(const ModbusClient&) = delete;

  std::vector<std::uint16_t> read(std::uint16_t addr, unsigned count);
  void write(std::uint16_t addr, std::span<const std::uint16_t> values);
  // FC23: writes first, then reads, in one exchange.
  std::vector<std::uint16_t> write_read(std::uint16_t waddr, std::span<const std::uint16_t> values,
                                        std::uint16_t raddr, unsigned count);

  const ModbusTarget& target() const { return target_; }
  const ModbusOptions& options() const { return opt_; }
  std::size_t exchanges() const { return exchanges_; }  // requests sent, retries included
  std::size_t retried() const { return retried_; }

 private:
  void connect();
  void disconnect();
  template <class F>
  void run(const std::string& what, F&& f);

  ModbusTarget target_;
  ModbusOptions opt_;
  modbus_t* ctx_ = nullptr;
  int serial_fd_ = -1;
  std::size_t exchanges_ = 0, retried_ = 0;
};

// What a scan of a Modbus coupler found.
struct ScanResult {
  std::string ident;    // identification registers, decoded
  std::string coupler;  // coupler profile used for the walk
  unsigned complex_out_bits = 0, complex_in_bits = 0, digital_out_bits = 0, digital_in_bits = 0;
  std::uint16_t watchdog_preset = 0, watchdog_type = 0;
  MappingSettings settings;
  StationSpec spec;       // the complex terminals found, with the registers that decide their image
  StationLayout layout;   // their layout
  std::vector<unsigned> r8;  // type number read from each terminal
  bool walked = false;    // complete evaluation on: terminals identified
  bool matches = false;   // the terminals found fill the complex area exactly
  std::vector<std::string> notes;
};

class ModbusLink : public Link {
 public:
  ModbusLink(ModbusTarget target, const Catalog& catalog, ModbusOptions opt);
  std::string describe() const override;
  void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) override;
  bool pipelines() const override { return true; }
  void write_outputs_read_inputs(std::size_t out_offset, std::span<const std::uint8_t> src, std::size_t in_offset,
                                 std::span<std::uint8_t> dst) override;
  void pause(unsigned poll_number) override;
  bool discovers_layout() const override { return true; }
  // Scans the coupler on first use (ScanResult); nullptr when the scan cannot identify terminals.
  const StationLayout* layout() override;
  const StationSpec* station() override;

  ModbusClient& client() { return client_; }
  const ScanResult& scan(const SessionOptions& so);  // once; later calls return the same result

 private:
  // Words [first, last] with the bytes of `src` at `offset`; the other bytes of those words come
  // from what the link last read or wrote, or are read first (never clobbered).
  std::vector<std::uint16_t> merge_words(std::size_t offset, std::span<const std::uint8_t> src);
  void remember_outputs(std::size_t first_word, std::span<const std::uint16_t> words);
  void wait_settled();
  void count() { exchanges_ = client_.exchanges(); }

  ModbusClient client_;
  const Catalog* catalog_;
  std::vector<int> out_cache_;  // output image bytes as the coupler holds them, -1 unknown
  std::chrono::steady_clock::time_point last_write_{};
  std::optional<ScanResult> scan_;
  bool scan_failed_ = false;
};

// Reads the identification, the image lengths and the watchdog registers, then (with complete
// evaluation) walks the complex area reading each terminal's R8 and mapping registers.
// `settings` overrides the coupler's defaults.
ScanResult scan_station(ModbusClient& client, Link& link, const Catalog& catalog, const SessionOptions& so,
                        std::optional<MappingSettings> settings = std::nullopt);

// Serial ports (libserialport).
struct SerialPortInfo {
  std::string name, description, transport;  // transport: native, usb, bluetooth
  int usb_vid = -1, usb_pid = -1;
  std::string manufacturer, product, serial;
};
std::vector<SerialPortInfo> list_serial_ports();

// ------------------------------------------------------------------------------------------
// The server behind `kscfg serve`.

struct ServeFaults {
  double drop = 0, delay = 0, corrupt = 0, busy = 0;  // rates 0..1 per request
  unsigned delay_ms = 100;
  bool any() const { return drop > 0 || delay > 0 || corrupt > 0 || busy > 0; }
};
// "drop=0.1,busy=0.05,delay=0.1,delay_ms=300,corrupt=0.02"; Error(Exit::usage) for bad items.
ServeFaults parse_faults(const std::string& spec);

struct ServeOptions {
  enum class Mode { tcp, rtu, pty } mode = Mode::tcp;
  std::string host = "127.0.0.1";
  unsigned port = 502;          // 0: any free port
  std::string device;           // rtu
  unsigned baud = 19200;
  char parity = 'E';
  unsigned data_bits = 8, stop_bits = 1;
  int unit = 1;                 // TCP: also answers 0 and 255
  unsigned cycle_us = 1000;     // K-bus cycle
  unsigned watchdog_ms = 1000;  // preset at power-on, 0 = off
  ServeFaults faults;
  std::uint64_t seed = 1;
  std::function<void(const std::string&)> trace;
};

struct ServeStats {
  std::size_t requests = 0, dropped = 0, delayed = 0, corrupted = 0, busy = 0, exceptions = 0, cycles = 0,
              watchdog_expired = 0;
};

class ModbusServer {
 public:
  // Binds/opens; Error(Exit::link/usage) when it cannot.
  ModbusServer(EmulatedStation& station, ServeOptions opt);
  ~ModbusServer();
  ModbusServer(const ModbusServer&) = delete;
  ModbusServer& operator=(const ModbusServer&) = delete;
  // The port URI a client uses: tcp://127.0.0.1:40123, rtu:/dev/pts/5?parity=N
  std::string endpoint() const;
  // Serves until `stop` is set (checked every 50 ms); the K-bus runs on its own thread meanwhile.
  void run(const std::atomic<bool>& stop);
  ServeStats stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kscfg
