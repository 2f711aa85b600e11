// AMS/TCP and ADS: the frame codec shared by kscfg's ADS client
// (link/ads_client.hpp) and serve's ADS server (emulator/ads_requests.hpp). Bytes in, values out:
// no sockets, bounded, so that it can be fuzzed (fuzz/fuzz_ams.cpp).
//
// Layout, little endian throughout (Beckhoff Information System, "AMS/TCP Packet",
// https://infosys.beckhoff.com/content/1033/tcadscommon/12440280843.html; "AMS/TCP Header",
// https://infosys.beckhoff.com/content/1033/tcadscommon/12440282379.html; "AMS Header",
// https://infosys.beckhoff.com/content/1033/tcadscommon/12440283915.html):
//   AMS/TCP header  6 bytes: reserved (0, 2 bytes), length of AMS header + data (4 bytes)
//   AMS header     32 bytes: target NetId (6), target port (2), source NetId (6), source port (2),
//                            command id (2), state flags (2), data length (4), error code (4),
//                            invoke id (4)
//   ADS data        n bytes
#pragma once
#include <sys/socket.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace kscfg::ams {

constexpr unsigned kTcpPort = 48898;  // "The TCP port number for the ADS protocol is 48898 or 0xBF02"
                                      // (BC9000 manual, "ADS protocol",
                                      // https://infosys.beckhoff.com/content/1033/bc9000/2802214411.html)
constexpr std::size_t kTcpHeader = 6, kAmsHeader = 32, kHeaders = kTcpHeader + kAmsHeader;
// "The user data of an ADS telegram is maximum 1900 byte" (BK/BC9000 "ADS services",
// https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html).
constexpr std::size_t kMaxUserData = 1900;
// What a frame's ADS data may hold at most: the user data and the largest command header
// (ReadWrite: index group, offset, read and write lengths) or response header (result, length).
// A longer frame is not one a BK/BC9000 sends or takes: the stream is dropped.
constexpr std::size_t kMaxData = kMaxUserData + 16;

// Command ids and state flags ("AMS Header", above). A coupler serves 1, 2, 3 and 9; a BK9050
// answered ReadState (4) with "unknown command ID" (AMS error 0x8), so kscfg never needs it.
enum Command : std::uint16_t {
  kReadDeviceInfo = 1,
  kRead = 2,
  kWrite = 3,
  kReadState = 4,
  kWriteControl = 5,
  kAddNotification = 6,
  kDeleteNotification = 7,
  kNotification = 8,
  kReadWrite = 9,
};
constexpr std::uint16_t kFlagResponse = 0x0001;    // 0: request, 1: response
constexpr std::uint16_t kFlagAdsCommand = 0x0004;  // must be set to exchange ADS commands
const char* command_name(std::uint16_t command);   // "Read", "ReadState", ...; "command N" is not given

// An AMS NetId: six bytes, written a.b.c.d.e.f. A coupler's is its IP address plus ".1.1"
// (BC9000 "ADS protocol", above).
using NetId = std::array<std::uint8_t, 6>;
std::optional<NetId> parse_netid(std::string_view text);  // strict: six numbers 0..255
std::string format_netid(const NetId& id);
NetId netid_of_ipv4(std::uint32_t host_order_address);  // a.b.c.d -> a.b.c.d.1.1
// The IPv4 address of a socket address, host order: IPv4, IPv4-mapped IPv6, and ::1 as 127.0.0.1;
// nullopt for any other IPv6 address.
std::optional<std::uint32_t> ipv4_of(const sockaddr_storage& sa);

struct Header {
  NetId target{};
  std::uint16_t target_port = 0;
  NetId source{};
  std::uint16_t source_port = 0;
  std::uint16_t command = 0;
  std::uint16_t flags = 0;
  std::uint32_t length = 0;  // of the data (encode() sets it)
  std::uint32_t error = 0;   // AMS error code (0: none)
  std::uint32_t invoke = 0;
  bool response() const { return (flags & kFlagResponse) != 0; }
};

struct Frame {
  Header header;
  std::vector<std::uint8_t> data;
};

// A whole AMS/TCP frame for `h` and `data` (the length fields are set from data).
std::vector<std::uint8_t> encode(Header h, std::span<const std::uint8_t> data);

// Where the first frame in a receive buffer ends. `invalid` means the stream is not AMS/TCP (the
// reserved field is not 0, the length is shorter than an AMS header or longer than kHeaders +
// kMaxData): whoever reads it must close the connection.
struct FrameCheck {
  enum Status { need_more, complete, invalid } status = need_more;
  std::size_t length = 0;  // complete: bytes of the frame
  std::string why;         // invalid: the reason
};
FrameCheck check_frame(std::span<const std::uint8_t> buf);
// The frame check_frame() found complete. Its header's length field must match the frame: a
// frame whose AMS data length disagrees with the AMS/TCP length is nullopt (`why` says so).
std::optional<Frame> decode(std::span<const std::uint8_t> frame, std::string* why = nullptr);

// ADS command data (Beckhoff "ADS Read", "ADS Write", "ADS Read Write", "ADS Read Device Info":
// https://infosys.beckhoff.com/content/1033/tc3_ads_intro/115876875.html and its siblings).
std::vector<std::uint8_t> read_request(std::uint32_t group, std::uint32_t offset, std::uint32_t length);
std::vector<std::uint8_t> write_request(std::uint32_t group, std::uint32_t offset, std::span<const std::uint8_t> data);
std::vector<std::uint8_t> read_write_request(std::uint32_t group, std::uint32_t offset, std::uint32_t read_length,
                                             std::span<const std::uint8_t> data);

struct Request {  // a Read, Write or ReadWrite request's fields, as a server sees them
  std::uint32_t group = 0, offset = 0;
  std::uint32_t read_length = 0;       // Read, ReadWrite
  std::span<const std::uint8_t> data;  // Write, ReadWrite (points into the frame's data)
};
// nullopt when the data does not hold the command's fields (or their lengths disagree).
std::optional<Request> parse_request(std::uint16_t command, std::span<const std::uint8_t> data);

// ADS sum commands: several reads and writes in one ReadWrite request, whose index group says
// which sum and whose index offset is the number of sub-commands (Beckhoff "ADS-sum command",
// https://infosys.beckhoff.com/content/1033/tc3_adsdll2/124835083.html: 0xF080 reads, 0xF081
// writes, 0xF082 reads and writes). The emulator serves 0xF082: the write data carries N x (index group,
// index offset, read length, write length), then every sub-command's write data in order; the
// answer carries N x (result, length read), then every sub-command's data read in order. The
// sub-commands are carried out in order. Not in the BK9000's documented ADS services: a coupler
// that does not serve it answers ADS error 0x701 or 0x702, or AMS error 0x8. kscfg's own client
// sends no sum command; the request side of the codec is kept beside the parse the server uses.
constexpr std::uint32_t kSumRead = 0xF080, kSumWrite = 0xF081, kSumReadWrite = 0xF082;
struct SumCall {
  std::uint32_t group = 0, offset = 0;
  std::uint32_t read_length = 0;
  std::span<const std::uint8_t> data;  // written (points into the caller's or the frame's bytes)
};
// The ReadWrite request data of a 0xF082 sum of `calls`.
std::vector<std::uint8_t> sum_read_write_request(std::span<const SumCall> calls);
// The sub-commands of a 0xF082 sum (`count` of them in `data`, the ReadWrite's write data);
// nullopt when their lengths disagree with the data.
std::optional<std::vector<SumCall>> parse_sum_read_write(std::uint32_t count, std::span<const std::uint8_t> data);

// Responses: result (ADS return code), then for Read and ReadWrite the length and the data;
// ReadDeviceInfo: result, major, minor, build, 16-byte name.
std::vector<std::uint8_t> result_response(std::uint32_t result);
std::vector<std::uint8_t> data_response(std::uint32_t result, std::span<const std::uint8_t> data);
std::vector<std::uint8_t> device_info_response(std::uint32_t result, std::uint8_t major, std::uint8_t minor,
                                               std::uint16_t build, std::string_view name);
struct Response {
  std::uint32_t result = 0;
  std::vector<std::uint8_t> data;  // Read, ReadWrite: the data; ReadDeviceInfo: version and name (20 bytes)
};
// nullopt when the data is too short for the command's response or its length field disagrees.
std::optional<Response> parse_response(std::uint16_t command, std::span<const std::uint8_t> data);
// The ReadWrite response data of a 0xF082 sum (the outer result first), and its parse: nullopt when
// it does not hold `count` answers whose lengths add up.
std::vector<std::uint8_t> sum_read_write_response(std::span<const Response> answers);
std::optional<std::vector<Response>> parse_sum_read_write_response(std::size_t count,
                                                                   std::span<const std::uint8_t> data);

// ADS return codes, by name (Beckhoff "ADS Return Codes",
// https://infosys.beckhoff.com/content/1033/tcdbserver/11407885707.html and
// https://infosys.beckhoff.com/content/1033/cx1100_000x/1549882891.html): "target port not found".
// An unknown code is "unknown error".
const char* error_name(std::uint32_t code);
// "AMS error 0x7 (target machine not found)" / "ADS error 0x702 (invalid index group)".
std::string error_text(std::uint32_t code);

std::uint16_t get16(const std::uint8_t* p);
std::uint32_t get32(const std::uint8_t* p);
void put16(std::vector<std::uint8_t>& v, std::uint16_t x);
void put32(std::vector<std::uint8_t>& v, std::uint32_t x);

}  // namespace kscfg::ams
