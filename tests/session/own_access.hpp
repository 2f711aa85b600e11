// A register access and engine of a test's own over an image link, and a session on them: what a
// test of the handshake builds. The library has no such session: a port has one access and engine
// (discovery/port.hpp open_port), and every register operation runs on them.
#pragma once
#include <utility>

#include "kscfg/link/link.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/handshake.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

struct HandshakeEngine {
  explicit HandshakeEngine(Link& link, const SessionOptions& so = {})
      : own_access(link, handshake_options(so)), own_engine(own_access) {}
  HandshakeAccess own_access;
  Engine own_engine;
  Engine& engine() { return own_engine; }  // also of a temporary, for one call
};

// RegisterSession on a HandshakeEngine of its own (built first, destroyed last).
class ImageSession : private HandshakeEngine, public RegisterSession {
 public:
  ImageSession(Link& link, const TerminalImage& terminal, unsigned channel, SessionOptions so = {})
      : HandshakeEngine(link, so), RegisterSession(HandshakeEngine::own_engine, terminal, channel, std::move(so)) {}
};

}  // namespace kscfg
