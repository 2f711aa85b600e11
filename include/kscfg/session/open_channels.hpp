// The channels a register access has open (access.hpp), each with its users and the program it
// runs: the bookkeeping both accesses share (HandshakeAccess, handshake.hpp; AdsAccess,
// ads_access.hpp), so that submit(), busy() and the counting of a channel's users are one code.
#pragma once
#include <fmt/format.h>

#include <algorithm>
#include <map>

#include "kscfg/base/error.hpp"
#include "kscfg/session/access.hpp"

namespace kscfg {

// What every open channel has, whatever the access.
struct OpenChannel {
  unsigned users = 1;       // opened this many times: its work ends when the last user closes it
  Program* prog = nullptr;  // the program it runs, from submit() until advance() returns it
  bool closed = false;      // its work ended (an access may keep the entry, as the handshake does)
};

// The open channels by key. `Chan` derives from OpenChannel.
template <class Chan>
class OpenChannels : public std::map<ChannelKey, Chan> {
 public:
  // RegisterAccess::open() of a channel already open counts one more user of it: true. False when
  // the channel is not open (never opened, or closed): the access opens it.
  bool reopen(ChannelKey key) {
    auto it = this->find(key);
    if (it == this->end() || it->second.closed) return false;
    ++it->second.users;
    return true;
  }
  // RegisterAccess::submit(): the channel must be open and run no other program.
  void submit(Program& p) {
    auto it = this->find(p.key);
    if (it == this->end() || it->second.closed)
      throw Error(Exit::internal, fmt::format("register access: terminal {} channel {} is not open", p.key.position,
                                              p.key.channel + 1));
    if (it->second.prog) throw Error(Exit::internal, "register access: a channel runs one program at a time");
    p.values.clear();
    p.error.reset();
    p.closed = false;
    it->second.prog = &p;
  }
  // RegisterAccess::busy(): a program submitted and not yet returned.
  bool busy() const {
    return std::any_of(this->begin(), this->end(), [](const auto& kv) { return kv.second.prog != nullptr; });
  }
};

}  // namespace kscfg
