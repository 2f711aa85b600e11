// SocketCanBus (link/slcan.hpp open_socketcan()): the CanBus over a raw CAN socket of the Linux
// kernel (PF_CAN, SOCK_RAW, CAN_RAW), and socketcan_available() for the tests that need a virtual
// CAN interface (vcan).
#include <errno.h>
#include <fmt/format.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/link/slcan.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr milliseconds kCanPollSlice{20};  // the cancel token is looked at this often (at most 50 ms)
constexpr milliseconds kSendWait{1000};    // a full transmit queue (ENOBUFS) is waited for this long
constexpr unsigned kArphrdCan = 280;       // ARPHRD_CAN (linux/if_arp.h)

std::string up_hint(const std::string& iface) {
  return fmt::format(
      "bring it up: ip link set {} up type can bitrate 500000 (a virtual one: ip link add dev {} "
      "type vcan && ip link set {} up)",
      iface, iface, iface);
}

class SocketCanBus final : public CanBus {
 public:
  SocketCanBus(int fd, std::string iface, const CancelToken* cancel)
      : fd_(fd), iface_(std::move(iface)), cancel_(cancel) {}
  ~SocketCanBus() override { ::close(fd_); }

  std::string describe() const override { return "socketcan:" + iface_; }
  std::size_t frames_sent() const override { return sent_; }

  void send(const CanFrame& f) override {
    can_frame k{};
    k.can_id = f.extended ? ((f.id & CAN_EFF_MASK) | CAN_EFF_FLAG) : (f.id & CAN_SFF_MASK);
    if (f.rtr) k.can_id |= CAN_RTR_FLAG;
    k.can_dlc = std::min<std::uint8_t>(f.len, 8);
    if (!f.rtr) std::copy_n(f.data.begin(), k.can_dlc, k.data);
    const auto deadline = Clock::now() + kSendWait;
    for (;;) {
      if (cancel_ && cancel_->cancelled()) throw Error(Exit::interrupted, "interrupted");
      ssize_t n = ::write(fd_, &k, sizeof k);
      if (n == static_cast<ssize_t>(sizeof k)) break;
      int e = n < 0 ? errno : EIO;
      if (e != EAGAIN && e != ENOBUFS && e != EINTR)
        throw Error(
            Exit::link,
            fmt::format("cannot send frame {} on CAN interface {}: {}", format_frame(f), iface_, std::strerror(e)),
            up_hint(iface_));
      if (Clock::now() >= deadline)
        throw Error(Exit::link,
                    fmt::format("CAN interface {} took no frame for {} ms (frame {}; its transmit queue stays full)",
                                iface_, kSendWait.count(), format_frame(f)),
                    "check that the bus is terminated and that another node acknowledges frames");
      if (e == ENOBUFS) {
        // The interface's queue is full while the socket's is not: poll() says writable at once.
        sleep_for_or_cancelled(milliseconds(1), cancel_);
        continue;
      }
      pollfd p{fd_, POLLOUT, 0};
      ::poll(&p, 1, static_cast<int>(kCanPollSlice.count()));
    }
    ++sent_;
  }

  std::optional<CanFrame> receive(Clock::time_point deadline) override {
    for (;;) {
      if (cancel_ && cancel_->cancelled()) throw Error(Exit::interrupted, "interrupted");
      can_frame k{};
      ssize_t n = ::read(fd_, &k, sizeof k);
      if (n == static_cast<ssize_t>(sizeof k)) {
        if (k.can_id & CAN_ERR_FLAG) continue;  // error frames (none unless asked for): not data
        CanFrame f;
        f.extended = (k.can_id & CAN_EFF_FLAG) != 0;
        f.rtr = (k.can_id & CAN_RTR_FLAG) != 0;
        f.id = k.can_id & (f.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
        f.len = std::min<std::uint8_t>(k.can_dlc, 8);
        if (!f.rtr) std::copy_n(k.data, f.len, f.data.begin());
        return f;
      }
      if (n >= 0 || (errno != EAGAIN && errno != EINTR))
        throw Error(Exit::link,
                    fmt::format("cannot receive on CAN interface {}: {}", iface_,
                                n >= 0 ? "a short frame" : std::strerror(errno)),
                    up_hint(iface_));
      // To the microsecond: the pause before an SDO upload is a fraction of a millisecond.
      auto left =
          std::max(std::chrono::ceil<std::chrono::microseconds>(deadline - Clock::now()), std::chrono::microseconds{0});
      if (left.count() == 0) return std::nullopt;
      pollfd p{fd_, POLLIN, 0};
      auto w = std::min<std::chrono::microseconds>(left, kCanPollSlice);
      timespec ts{static_cast<time_t>(w.count() / 1000000), static_cast<long>(w.count() % 1000000) * 1000};
      ::ppoll(&p, 1, &ts, nullptr);
    }
  }

 private:
  int fd_;
  std::string iface_;
  const CancelToken* cancel_;
  std::size_t sent_ = 0;
};

std::string read_line_of(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::string s;
  std::getline(in, s);
  return s;
}

}  // namespace

std::unique_ptr<CanBus> open_socketcan(const std::string& iface, const CancelToken* cancel) {
  if (iface.empty() || iface.size() >= IFNAMSIZ)
    throw Error(Exit::usage,
                fmt::format("'{}' is not a network interface name (1..{} characters)", iface, IFNAMSIZ - 1));
  int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    int e = errno;
    bool exists = ::if_nametoindex(iface.c_str()) != 0;
    throw Error(Exit::link,
                fmt::format("cannot open CAN interface {}: {}this machine's kernel offers no SocketCAN ({})", iface,
                            exists ? "" : "there is no such interface, and ", std::strerror(e)),
                "load the CAN modules (modprobe can_raw), then: ip link set can0 up type can bitrate 500000");
  }
  auto fail = [&](std::string message, std::string hint) {
    ::close(fd);
    return Error(Exit::link, std::move(message), std::move(hint));
  };
  ifreq ifr{};
  std::memcpy(ifr.ifr_name, iface.c_str(), iface.size());
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
    int e = errno;
    throw fail(e == ENODEV ? fmt::format("CAN interface {} does not exist", iface)
                           : fmt::format("cannot find CAN interface {}: {}", iface, std::strerror(e)),
               "'ip link' lists the interfaces; a CAN one is brought up with: ip link set can0 up type can bitrate "
               "500000");
  }
  const int index = ifr.ifr_ifindex;
  if (::ioctl(fd, SIOCGIFFLAGS, &ifr) == 0 && !(ifr.ifr_flags & IFF_UP))
    throw fail(fmt::format("CAN interface {} is down", iface), up_hint(iface));
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = index;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    int e = errno;
    throw fail(e == ENETDOWN ? fmt::format("CAN interface {} is down", iface)
               : e == EINVAL || e == ENODEV
                   ? fmt::format("{} is not a CAN interface", iface)
                   : fmt::format("cannot bind to CAN interface {}: {}", iface, std::strerror(e)),
               up_hint(iface));
  }
  return std::make_unique<SocketCanBus>(fd, iface, cancel);
}

std::optional<std::string> vcan_interface() {
  namespace fs = std::filesystem;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/sys/class/net", ec)) {
    // A virtual CAN interface: type ARPHRD_CAN and no device behind it; up (IFF_UP in its flags).
    if (read_line_of(e.path() / "type") != std::to_string(kArphrdCan) || fs::exists(e.path() / "device", ec)) continue;
    unsigned long flags = 0;
    try {
      flags = std::stoul(read_line_of(e.path() / "flags"), nullptr, 16);
    } catch (...) {
      continue;
    }
    if (flags & IFF_UP) return e.path().filename().string();
  }
  return std::nullopt;
}

bool socketcan_available() {
  int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) return false;
  ::close(fd);
  if (vcan_interface()) return true;
  // None up yet: one can be made where the vcan module is loaded and this process may add links.
  std::error_code ec;
  return std::filesystem::exists("/sys/module/vcan", ec) && ::geteuid() == 0;
}

}  // namespace kscfg
