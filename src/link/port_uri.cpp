#include "kscfg/link/port_uri.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

namespace {

std::map<std::string, std::string> parse_query(const std::string& uri, const std::string& q) {
  std::map<std::string, std::string> out;
  std::size_t pos = 0;
  while (pos <= q.size()) {
    auto amp = q.find('&', pos);
    std::string kv = q.substr(pos, amp == std::string::npos ? std::string::npos : amp - pos);
    auto eq = kv.find('=');
    if (kv.empty() || eq == std::string::npos || eq == 0 || eq + 1 == kv.size())
      throw Error(Exit::usage, fmt::format("invalid port {}: query items are key=value", quote_input(uri)));
    // A key given twice is refused, not the last one taken: "?node=3&node=4" would reach node 4.
    if (!out.emplace(kv.substr(0, eq), kv.substr(eq + 1)).second)
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: {} is given twice", quote_input(uri), quote_input(kv.substr(0, eq))));
    if (amp == std::string::npos) break;
    pos = amp + 1;
  }
  return out;
}

// The scheme of a tcp, ads, rtu, slcan or socketcan URI into p; the text after it.
std::string split_scheme(const std::string& uri, PortUri& p) {
  std::string rest;
  if (uri.rfind("tcp://", 0) == 0) {
    p.scheme = "tcp";
    rest = uri.substr(6);
  } else if (uri.rfind("ads://", 0) == 0) {
    p.scheme = "ads";
    p.port = 48898;  // AMS/TCP (link/ams.hpp)
    rest = uri.substr(6);
  } else if (uri.rfind("rtu:", 0) == 0) {
    p.scheme = "rtu";
    rest = uri.substr(4);
  } else if (uri.rfind("slcan:", 0) == 0 || uri.rfind("socketcan:", 0) == 0) {
    // slcan:DEVICE and slcan://DEVICE (slcan:///dev/ttyACM0 is /dev/ttyACM0); socketcan alike.
    p.scheme = uri.substr(0, uri.find(':'));
    rest = uri.substr(p.scheme.size() + 1);
    if (rest.rfind("//", 0) == 0) rest.erase(0, 2);
  } else {
    throw Error(Exit::usage, fmt::format("invalid port {}: use emu, emu:PATH, tcp://HOST[:PORT], ads://HOST[:PORT], "
                                         "rtu:DEVICE, slcan:DEVICE or socketcan:IFACE",
                                         quote_input(uri)));
  }
  return rest;
}

// tcp:// and ads://: HOST[:PORT], an IPv6 address in brackets ([::1]:502).
void parse_host_port(const std::string& uri, std::string rest, PortUri& p) {
  std::string port_text;
  bool has_port = false;
  if (!rest.empty() && rest.front() == '[') {  // [IPv6]:port
    auto close = rest.find(']');
    if (close == std::string::npos)
      throw Error(Exit::usage, fmt::format("invalid port {}: missing ']'", quote_input(uri)));
    if (close + 1 < rest.size()) {
      if (rest[close + 1] != ':') throw Error(Exit::usage, fmt::format("invalid port {}", quote_input(uri)));
      port_text = rest.substr(close + 2);
      has_port = true;
    }
    rest = rest.substr(1, close - 1);
  } else if (auto colon = rest.rfind(':'); colon != std::string::npos) {
    port_text = rest.substr(colon + 1);
    rest.resize(colon);
    has_port = true;
  }
  if (has_port) {
    p.port = static_cast<unsigned>(parse_uint(port_text, 65535, "TCP port"));
    if (p.port == 0) throw Error(Exit::usage, fmt::format("invalid port {}: TCP port 0", quote_input(uri)));
  }
  if (rest.empty()) throw Error(Exit::usage, fmt::format("invalid port {}: no host", quote_input(uri)));
  p.target = rest;
  for (const auto& [k, v] : p.query) {
    if (p.scheme == "tcp" && k != "unit")
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: unknown option {} (unit)", quote_input(uri), quote_input(k)));
    if (p.scheme == "ads" && k != "netid" && k != "source")
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: unknown option {} (netid, source)", quote_input(uri), quote_input(k)));
  }
}

// socketcan://IFACE: an interface name as the kernel takes it, 1..15 characters, no '/', ':' or blank.
void parse_socketcan(const std::string& uri, const std::string& rest, PortUri& p) {
  if (rest.empty()) throw Error(Exit::usage, fmt::format("invalid port {}: no interface", quote_input(uri)));
  if (rest.size() > 15 || rest == "." || rest == ".." ||
      std::any_of(rest.begin(), rest.end(), [](char c) { return c == '/' || c == ':' || c <= ' ' || c > '~'; }))
    throw Error(Exit::usage,
                fmt::format("invalid port {}: {} is not a network interface name", quote_input(uri), quote_input(rest)),
                "give the CAN interface as 'ip link' lists it, e.g. socketcan://can0");
  p.target = rest;
  for (const auto& [k, v] : p.query) {
    if (k == "bitrate")
      throw Error(
          Exit::usage,
          fmt::format("invalid port {}: a SocketCAN interface has its bit rate set by the system", quote_input(uri)),
          fmt::format("drop ?bitrate=; set it with 'ip link set {} up type can bitrate 500000'", rest));
    if (k != "node")
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: unknown option {} (node)", quote_input(uri), quote_input(k)));
  }
}

}  // namespace

PortUri parse_port_uri(const std::string& uri) {
  // No device path, host or interface name is this long (PATH_MAX): refused before any is used as a
  // file name (the lock file's, the device's), each of which would echo it whole.
  constexpr std::size_t kMaxUri = 4096;
  if (uri.size() > kMaxUri)
    throw Error(Exit::usage, fmt::format("invalid port {}: longer than {} bytes", quote_input(uri), kMaxUri));
  PortUri p;
  if (uri == "emu" || uri.rfind("emu:", 0) == 0) {
    p.scheme = "emu";
    p.target = uri.size() > 4 ? uri.substr(4) : "";
    if (uri == "emu:") throw Error(Exit::usage, "invalid port 'emu:': give a state file path, or 'emu'");
    return p;
  }
  std::string rest = split_scheme(uri, p);
  auto qm = rest.find('?');
  if (qm != std::string::npos) {
    p.query = parse_query(uri, rest.substr(qm + 1));
    rest.resize(qm);
  }
  if (p.scheme == "tcp" || p.scheme == "ads") {
    parse_host_port(uri, rest, p);
  } else if (p.scheme == "slcan") {
    if (rest.empty()) throw Error(Exit::usage, fmt::format("invalid port {}: no device", quote_input(uri)));
    p.target = rest;
    for (const auto& [k, v] : p.query)
      if (k != "bitrate" && k != "node")
        throw Error(Exit::usage, fmt::format("invalid port {}: unknown option {} (bitrate, node)", quote_input(uri),
                                             quote_input(k)));
  } else if (p.scheme == "socketcan") {
    parse_socketcan(uri, rest, p);
  } else {
    if (rest.empty()) throw Error(Exit::usage, fmt::format("invalid port {}: no device", quote_input(uri)));
    p.target = rest;
    for (const auto& [k, v] : p.query)
      if (k != "unit" && k != "baud" && k != "parity" && k != "data" && k != "stop")
        throw Error(Exit::usage, fmt::format("invalid port {}: unknown option {} (baud, parity, data, stop, unit)",
                                             quote_input(uri), quote_input(k)));
  }
  return p;
}

}  // namespace kscfg
