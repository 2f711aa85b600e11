// The transports' openers and what they share (port.cpp's scheme table calls one per URI). Private
// to the discovery layer: everything else opens a port with open_port() (discovery/port.hpp).
#pragma once
#include <functional>
#include <memory>
#include <string>

#include "kscfg/discovery/port.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg {

std::unique_ptr<Port> open_emulator_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                         const LinkOptions& opt);
std::unique_ptr<Port> open_modbus_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                       const LinkOptions& opt);
std::unique_ptr<Port> open_ads_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                    const LinkOptions& opt);
std::unique_ptr<Port> open_can_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                    const LinkOptions& opt);

// The options of the port's access and of discovery's sessions (LinkOptions::session).
SessionOptions port_session(const LinkOptions& opt);

// What dead kscfg processes left on a port whose registers go through the process image (the
// emulator, a Modbus coupler): their register-mode sessions and forced outputs, each entry checked
// against the terminal at its position.
void recover_image_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                            const std::function<const StationLayout&(unsigned upto)>& layout_upto);
// ... on a port with direct register access (ADS port 100, CANopen SDO): the channels a dead
// kscfg unlocked; `image`: where a dead `data force` may have forced outputs (nullptr: kscfg moves
// no image there).
void recover_direct_sessions(Engine& engine, Link* image, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned upto)>& layout_upto);

// The station a port's direct access numbers its terminals from: `given` (the command's station)
// or, without one, what the discovery found; `what` names the coupler in the error.
std::function<const StationLayout&()> numbering_layout(std::function<const StationLayout&()> given,
                                                       StationDiscovery* discovery, const char* what);

}  // namespace kscfg
