#include "kscfg/link/coupler_key.hpp"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netdb.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/owner_lock.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/can_link.hpp"

namespace kscfg {

namespace {

constexpr unsigned kModbusPort = 502;

std::string safe(const std::string& s) {
  std::string o;
  for (char c : s) o += std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' ? c : '_';
  return o;
}

// The key of every address of this computer: a listener on 0.0.0.0 or :: (`kscfg serve --tcp [::]:P`,
// a gateway program) answers each of them, so they reach one coupler.
constexpr char kThisComputer[] = "127.0.0.1";

// An address of this computer: loopback (127/8, ::1), the unspecified address (connect() takes it
// for this computer), or one of its interfaces' addresses.
bool this_computer(const sockaddr* sa) {
  if (sa->sa_family == AF_INET) {
    std::uint32_t a = ntohl(reinterpret_cast<const sockaddr_in*>(sa)->sin_addr.s_addr);
    if ((a >> 24) == 127 || a == 0) return true;
  } else if (sa->sa_family == AF_INET6) {
    const in6_addr& a = reinterpret_cast<const sockaddr_in6*>(sa)->sin6_addr;
    if (IN6_IS_ADDR_LOOPBACK(&a) || IN6_IS_ADDR_UNSPECIFIED(&a)) return true;
  } else {
    return false;
  }
  ifaddrs* list = nullptr;
  if (getifaddrs(&list) != 0) return false;
  bool mine = false;
  for (ifaddrs* i = list; i && !mine; i = i->ifa_next) {
    if (!i->ifa_addr || i->ifa_addr->sa_family != sa->sa_family) continue;
    if (sa->sa_family == AF_INET)
      mine = reinterpret_cast<const sockaddr_in*>(i->ifa_addr)->sin_addr.s_addr ==
             reinterpret_cast<const sockaddr_in*>(sa)->sin_addr.s_addr;
    else
      mine = std::memcmp(&reinterpret_cast<const sockaddr_in6*>(i->ifa_addr)->sin6_addr,
                         &reinterpret_cast<const sockaddr_in6*>(sa)->sin6_addr, sizeof(in6_addr)) == 0;
  }
  freeifaddrs(list);
  return mine;
}

std::string resolve(const std::string& host) {
  addrinfo hints{}, *res = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  if (int rc = getaddrinfo(host.c_str(), nullptr, &hints, &res); rc != 0)
    throw Error(Exit::link, fmt::format("cannot resolve host '{}': {}", host, gai_strerror(rc)),
                "check the host name or give an IP address");
  std::optional<std::uint32_t> v4;                                            // host order, the lowest
  std::optional<std::pair<std::array<unsigned char, 16>, std::uint32_t>> v6;  // bytes and scope, the lowest
  for (addrinfo* ai = res; ai; ai = ai->ai_next) {
    if (ai->ai_family == AF_INET) {
      std::uint32_t a = ntohl(reinterpret_cast<const sockaddr_in*>(ai->ai_addr)->sin_addr.s_addr);
      if (!v4 || a < *v4) v4 = a;
    } else if (ai->ai_family == AF_INET6) {
      const auto* s6 = reinterpret_cast<const sockaddr_in6*>(ai->ai_addr);
      if (IN6_IS_ADDR_V4MAPPED(&s6->sin6_addr)) {
        std::uint32_t a = 0;
        std::memcpy(&a, s6->sin6_addr.s6_addr + 12, 4);
        a = ntohl(a);
        if (!v4 || a < *v4) v4 = a;
        continue;
      }
      std::pair<std::array<unsigned char, 16>, std::uint32_t> b;
      std::memcpy(b.first.data(), s6->sin6_addr.s6_addr, 16);
      b.second = s6->sin6_scope_id;
      if (!v6 || b < *v6) v6 = b;
    }
  }
  freeaddrinfo(res);
  char text[INET6_ADDRSTRLEN + IF_NAMESIZE + 2] = {};
  if (v4) {
    sockaddr_in sa{};
    sa.sin_family = AF_INET;
    sa.sin_addr.s_addr = htonl(*v4);
    if (this_computer(reinterpret_cast<const sockaddr*>(&sa))) return kThisComputer;
    inet_ntop(AF_INET, &sa.sin_addr, text, sizeof text);
    return text;
  }
  if (v6) {
    sockaddr_in6 sa{};
    sa.sin6_family = AF_INET6;
    std::memcpy(sa.sin6_addr.s6_addr, v6->first.data(), 16);
    if (this_computer(reinterpret_cast<const sockaddr*>(&sa))) return kThisComputer;
    inet_ntop(AF_INET6, &sa.sin6_addr, text, sizeof text);
    std::string out = text;
    if (v6->second != 0) {  // a link-local address is one per interface
      char name[IF_NAMESIZE] = {};
      out += "%" + std::string(if_indextoname(v6->second, name) ? name : std::to_string(v6->second).c_str());
    }
    return out;
  }
  throw Error(Exit::link, fmt::format("cannot resolve host '{}': no IPv4 or IPv6 address", host),
              "check the host name or give an IP address");
}

std::string alias_path(const std::string& key) {
  return (std::filesystem::path(lock_dir()) / ("alias-" + key)).string();
}

// The key `key` stands for while a listener's CouplerAlias records it; `key` when none does (no
// record, a process that is gone or is not a kscfg of the record's owner, a record that is not one).
// Only listeners of this computer are aliased: a record never speaks for a coupler elsewhere.
// A key of this computer: a listener on one of its addresses, a serial line or CAN interface of its
// own (a pseudo-terminal a serve plays an adapter on, a SocketCAN interface).
bool local_key(const std::string& key) {
  return key.rfind(std::string("ip-") + kThisComputer + "-", 0) == 0 || key.rfind("rtu-", 0) == 0 ||
         key.rfind("can-", 0) == 0;
}

std::string aliased(const std::string& key) {
  if (!local_key(key)) return key;
  std::string path;
  try {
    path = alias_path(key);
  } catch (const Error&) {
    return key;  // no lock directory: nothing recorded either
  }
  RegularFile r = read_regular_file(path, "coupler alias", 512);
  if (!r.exists || !r.refused.empty() || !S_ISREG(r.mode) || r.nlink != 1) return key;
  // Written by this user or by root, and no one else can write it: another user's record would
  // send this kscfg to a lock nobody holds (root's write went through while another root kscfg
  // held the coupler).
  if ((r.uid != 0 && r.uid != ::geteuid()) || (r.mode & (S_IWGRP | S_IWOTH))) return key;
  auto nl = r.text.find('\n');
  if (nl == std::string::npos || nl == 0 || nl > 10) return key;
  std::string pid = r.text.substr(0, nl), to = r.text.substr(nl + 1);
  if (!to.empty() && to.back() == '\n') to.pop_back();
  if (!std::all_of(pid.begin(), pid.end(), [](char c) { return c >= '0' && c <= '9'; }) || !local_key(to) ||
      to.size() > 200 || safe(to) != to)
    return key;
  // Its writer: a kscfg of the record's owner that still runs.
  struct stat ps {};
  std::string proc = "/proc/" + pid;
  if (::stat(proc.c_str(), &ps) != 0 || ps.st_uid != r.uid) return key;
  RegularFile comm = read_regular_file(proc + "/comm", "process name", 64);
  if (!comm.exists || !comm.refused.empty() || comm.text != "kscfg\n") return key;
  return to;
}

std::string raw_ip_key(const std::string& host, unsigned port, unsigned standard) {
  std::string a = safe(host_key_address(host));
  return port == standard ? "ip-" + a : fmt::format("ip-{}-{}", a, port);
}

std::string ip_key(const std::string& host, unsigned port, unsigned standard) {
  return aliased(raw_ip_key(host, port, standard));
}

// The first line of the record at `path`: the PID of its writer ("" when there is none).
std::string record_pid(const std::string& path) {
  RegularFile r = read_regular_file(path, "coupler alias", 512);
  if (!r.exists || !r.refused.empty()) return "";
  return r.text.substr(0, r.text.find('\n'));
}

// A serial device as the kernel knows it; one that is not there (yet) by its absolute path, and its
// open says what is wrong.
std::string device_key(const std::string& device) {
  std::error_code ec;
  std::filesystem::path real = std::filesystem::canonical(device, ec);
  if (ec) real = std::filesystem::weakly_canonical(std::filesystem::absolute(device, ec), ec);
  if (ec) real = device;
  // A lock file's name has at most 255 bytes (NAME_MAX): a longer key (a device path no adapter has;
  // its open says what is wrong) is cut, with the FNV-1a hash of the whole so that two stay two.
  std::string key = safe(real.string());
  constexpr std::size_t kMaxKey = 180;
  if (key.size() <= kMaxKey) return key;
  std::uint64_t h = 0xcbf29ce484222325ULL;
  for (unsigned char c : real.string()) h = (h ^ c) * 0x100000001b3ULL;
  return fmt::format("{}-{:016x}", key.substr(0, kMaxKey - 17), h);
}

}  // namespace

std::string host_key_address(const std::string& host) {
  static std::mutex m;
  static std::map<std::string, std::string> known;
  {
    std::lock_guard<std::mutex> g(m);
    if (auto it = known.find(host); it != known.end()) return it->second;
  }
  std::string a = resolve(host);
  std::lock_guard<std::mutex> g(m);
  return known.emplace(host, a).first->second;
}

// A serial line: one program at a time, whatever it speaks on it (Modbus RTU, slcan).
std::string serial_key(const std::string& device) { return "rtu-" + device_key(device); }

std::string coupler_key(const ModbusTarget& t) {
  if (t.tcp) return ip_key(t.host, t.port, kModbusPort);
  return aliased(serial_key(t.device));
}

std::string coupler_key(const AdsTarget& t) { return ip_key(t.host, t.port, ams::kTcpPort); }

std::string coupler_key(const CanTarget& t) {
  return fmt::format("can-{}-n{}", t.scheme == "slcan" ? device_key(t.device) : safe(t.device), t.node);
}

std::string lock_key(const CanTarget& t) { return aliased(listener_key(t)); }

std::string listener_key(const ModbusTarget& t) {
  return t.tcp ? raw_ip_key(t.host, t.port, kModbusPort) : serial_key(t.device);
}

std::string listener_key(const CanTarget& t) { return t.scheme == "slcan" ? serial_key(t.device) : coupler_key(t); }

std::vector<std::string> pty_peers(const std::string& device) {
  // The pseudo-terminal's number, then the process holding its master (/dev/ptmx with that
  // tty-index in its fdinfo), then that process's other masters.
  std::error_code ec;
  const std::string real = std::filesystem::canonical(device, ec).string();
  if (ec || real.rfind("/dev/pts/", 0) != 0) return {};
  const std::string index = real.substr(9);
  auto tty_index = [](const std::filesystem::path& fdinfo) {
    RegularFile f = read_regular_file(fdinfo.string(), "fdinfo", 4096);
    auto at = f.text.find("tty-index:");
    if (at == std::string::npos) return std::string();
    std::string v = f.text.substr(at + 10, f.text.find('\n', at) - at - 10);
    v.erase(0, v.find_first_not_of(" \t"));
    return v;
  };
  for (const auto& proc : std::filesystem::directory_iterator("/proc", ec)) {
    const std::string pid = proc.path().filename().string();
    if (pid.empty() || !std::all_of(pid.begin(), pid.end(), [](char c) { return c >= '0' && c <= '9'; })) continue;
    std::vector<std::string> masters;  // tty-index of each /dev/ptmx it holds
    std::error_code e2;
    for (const auto& fd : std::filesystem::directory_iterator(proc.path() / "fd", e2)) {
      std::error_code e3;
      std::string target = std::filesystem::read_symlink(fd.path(), e3).string();
      if (e3 || (target != "/dev/ptmx" && target != "/dev/pts/ptmx")) continue;
      std::string n = tty_index(proc.path() / "fdinfo" / fd.path().filename());
      if (!n.empty()) masters.push_back(n);
    }
    if (std::find(masters.begin(), masters.end(), index) == masters.end()) continue;
    std::vector<std::string> peers;
    for (const auto& n : masters)
      if (n != index) peers.push_back("/dev/pts/" + n);
    return peers;
  }
  return {};
}

std::string listener_key(const AdsTarget& t) { return raw_ip_key(t.host, t.port, ams::kTcpPort); }

CouplerAlias::CouplerAlias(const std::string& also, const std::string& key) {
  if (also == key) return;
  std::error_code ec;
  std::filesystem::create_directories(lock_dir(), ec);
  std::string path = alias_path(also);
  // A live record of another listener of one of these keys (127.0.0.2:P and 127.0.0.1:P are one key)
  // stays as it is: replaced, or a record made to point at a key that stands for another, clients
  // of one coupler would take two locks.
  auto taken = [&](const std::string& what) {
    return Error(Exit::file,
                 fmt::format("{} is recorded by another kscfg serve (lock directory {})", what, lock_dir()));
  };
  if (aliased(also) != also) throw taken("coupler key " + also);
  if (aliased(key) != key) throw taken("coupler key " + key);
  for (const auto& e : std::filesystem::directory_iterator(lock_dir(), ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("alias-", 0) == 0 && name.substr(6) != also && aliased(name.substr(6)) == also)
      throw taken("a coupler key standing for " + also);
  }
  write_file_atomic(path, fmt::format("{}\n{}\n", ::getpid(), key), true);  // a link there replaced, not followed
  path_ = path;
}

CouplerAlias::~CouplerAlias() {
  // Only its own record: not one another serve wrote since.
  if (!path_.empty() && record_pid(path_) == std::to_string(::getpid())) ::unlink(path_.c_str());
}

std::string station_key(const ModbusTarget& t) { return fmt::format("{}-unit{}", coupler_key(t), t.unit); }

std::string station_key(const AdsTarget& t) { return coupler_key(t) + "-ads"; }

std::string station_key(const CanTarget& t) { return coupler_key(t); }

}  // namespace kscfg
