// The listening socket of `kscfg serve`, for Modbus TCP and ADS alike (internal to the emulator).
#pragma once
#include <string>

struct sockaddr_storage;

namespace kscfg {

struct TcpListener {
  int fd = -1;            // non-blocking, close-on-exec, SO_REUSEADDR
  unsigned port = 0;      // the port bound (port 0 asked: the one the system chose)
  bool loopback = false;  // bound to a loopback address
};

// Listens on HOST ("*": every address) and PORT (0: any free one). Error(link) with a hint when
// the name does not resolve or no address can be bound.
TcpListener listen_tcp(const std::string& host, unsigned port);

// "ADDR:PORT" or "[ADDR6]:PORT" of a peer, for messages; "?" for another family.
std::string peer_name(const sockaddr_storage& sa);

}  // namespace kscfg
