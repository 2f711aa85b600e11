#include "tcp_listen.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstring>

#include "kscfg/base/error.hpp"
#include "kscfg/link/ams.hpp"

namespace kscfg {

TcpListener listen_tcp(const std::string& host, unsigned port) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* res = nullptr;
  std::string service = std::to_string(port);
  const char* node = host == "*" ? nullptr : host.c_str();
  if (int e = getaddrinfo(node, service.c_str(), &hints, &res); e != 0)
    throw Error(Exit::link, fmt::format("cannot listen on {}:{}: {}", host, port, gai_strerror(e)));
  TcpListener l;
  int err = 0;
  for (addrinfo* ai = res; ai && l.fd < 0; ai = ai->ai_next) {
    int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      err = errno;
      continue;
    }
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (::bind(fd, ai->ai_addr, ai->ai_addrlen) != 0 || ::listen(fd, SOMAXCONN) != 0) {
      err = errno;
      ::close(fd);
      continue;
    }
    l.fd = fd;
  }
  freeaddrinfo(res);
  if (l.fd < 0)
    throw Error(Exit::link, fmt::format("cannot listen on {}:{}: {}", host, port, std::strerror(err)),
                err == EADDRINUSE ? "another program uses that port; choose another, or port 0 for any free one"
                : err == EACCES   ? "ports below 1024 need privileges; use a higher port"
                                  : "");
  sockaddr_storage sa{};
  socklen_t sl = sizeof sa;
  getsockname(l.fd, reinterpret_cast<sockaddr*>(&sa), &sl);
  l.port = ntohs(sa.ss_family == AF_INET6 ? reinterpret_cast<sockaddr_in6*>(&sa)->sin6_port
                                          : reinterpret_cast<sockaddr_in*>(&sa)->sin_port);
  // IPv4 127/8, ::1, or an IPv4-mapped 127/8.
  auto a = ams::ipv4_of(sa);
  l.loopback = a && (*a >> 24) == 127;
  return l;
}

std::string peer_name(const sockaddr_storage& sa) {
  char host[INET6_ADDRSTRLEN] = "?";
  if (sa.ss_family == AF_INET) {
    auto* a = reinterpret_cast<const sockaddr_in*>(&sa);
    inet_ntop(AF_INET, &a->sin_addr, host, sizeof host);
    return fmt::format("{}:{}", host, ntohs(a->sin_port));
  }
  if (sa.ss_family == AF_INET6) {
    auto* a = reinterpret_cast<const sockaddr_in6*>(&sa);
    inet_ntop(AF_INET6, &a->sin6_addr, host, sizeof host);
    return fmt::format("[{}]:{}", host, ntohs(a->sin6_port));
  }
  return "?";
}

}  // namespace kscfg
