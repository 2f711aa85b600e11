// A coupler's identity on this computer, whatever name it was reached by
// (docs/design.md 6.9): the one key behind its lock file, its session journals and its scan cache.
//
// Hosts are keyed by their numeric address (getaddrinfo): `localhost`, `127.0.0.1` and any other
// name of one address are one key. A name with several addresses is keyed by the lowest IPv4
// address (numerically; an IPv4-mapped IPv6 address counts as IPv4), or, with no IPv4 address, by
// the lowest IPv6 address (bytewise). Beckhoff couplers speak IPv4 only, so a name's IPv4 address is
// the coupler's. Every address of this computer (127/8, ::1, 0.0.0.0, ::, its interfaces' addresses)
// is one host, keyed "127.0.0.1": a listener on :: or 0.0.0.0 (`kscfg serve --tcp [::]:P`, a gateway
// program) answers them all. Two listeners on two of them then take turns, which is safe; two keys for
// one listener were not (two sessions undo each other's writes). A name that does not resolve is
// Error(Exit::link), as the connect would say.
//
// Modbus TCP on the standard port 502 and ADS on the standard AMS/TCP port 48898 of one address
// are one coupler (a BK9000 answers both), keyed by the address alone: "ip-10.0.3.11". The Modbus
// unit id is not part of it: a BK9000 is one coupler whatever unit a request names, and the units
// of a Modbus gateway take turns, which is safe. On any other port (a `kscfg serve` on a high port,
// the test suite's many serves side by side on 127.0.0.1) the key is address and port,
// "ip-127.0.0.1-5020": only one listener can have a port, so the protocol need not be in it.
//
// A listener that serves one coupler by several protocols (`kscfg serve --tcp P1 --ads P2`, as a
// BK9000 answers Modbus TCP on 502 and ADS on 48898; `--can slcan:PATH` beside them) records that
// every other client key stands for the first's while it lives (CouplerAlias): clients over every
// protocol then take one lock and turns. A record is used only for keys of this computer (a
// listener on one of its addresses, a serial line, a CAN interface), and only when it is a regular
// file of root or of this user that no one else may write, whose owner runs the kscfg process it
// names.
//
// A serial device is keyed by its real path (realpath: a /dev/serial/by-id/ link and its target
// are one key), whatever the unit: one master at a time on a line. "rtu-_dev_ttyUSB0".
//
// A CANopen coupler (link/can_link.hpp) is keyed by its CAN interface and its node id: an slcan
// adapter by the real path of its serial device, a SocketCAN interface by its name, plus the node:
// "can-_dev_ttyACM0-n3", "can-can0-n3". SDO transfers to two nodes do not disturb each other; two
// clients of one node would mix their transfers (one SDO channel per node) and take turns.
#pragma once
#include <string>
#include <vector>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/modbus_client.hpp"

namespace kscfg {

struct CanTarget;  // link/can_link.hpp

// The numeric address that keys `host` (the rule above): "10.0.3.11", "fd00::7", "fe80::1%eth0", and
// "127.0.0.1" for every address of this computer.
// Resolved once per process and host. Error(Exit::link) when the name does not resolve.
std::string host_key_address(const std::string& host);

// The coupler's identity, usable as a file name: "ip-ADDR" (standard ports), "ip-ADDR-PORT",
// "rtu-DEVICE". Modbus TCP and ADS to one coupler give one key.
std::string coupler_key(const ModbusTarget& target);
std::string coupler_key(const AdsTarget& target);
// "can-_dev_ttyACM0-n3" (slcan), "can-can0-n3" (SocketCAN).
std::string coupler_key(const CanTarget& target);
// What a CAN target's lock stands for (discovery/open.hpp coupler_lock_path()): an slcan adapter
// is one program's at a time (open_serial() locks its tty), so every node behind it takes the lock
// of its serial line, the one an RTU link on that device takes ("rtu-_dev_ttyACM0"): kscfg
// processes on two nodes of one adapter, or on one tty by rtu: and slcan:, take turns; a SocketCAN
// interface is shared: its node's coupler_key().
std::string lock_key(const CanTarget& target);

// A listener's own key, records not followed: what a CouplerAlias is made of. For a serial line
// or a CAN interface: the key of a client that opens that device ("rtu-_dev_pts_4", "can-vcan0-n1").
std::string listener_key(const ModbusTarget& target);
std::string listener_key(const AdsTarget& target);
std::string listener_key(const CanTarget& target);

// The other ends of the pseudo-terminal `device` when a process of this computer relays it to
// others (socat pty pty, a test's relay): /dev/pts/M for each other pseudo-terminal master the
// process that holds `device`'s master has open. Empty when `device` is no pseudo-terminal or no
// such process can be seen. What a client of a `kscfg serve --rtu PATH` or `--can slcan:PATH` opens.
std::vector<std::string> pty_peers(const std::string& device);

// While it lives, coupler key `also` stands for `key` (the rule above): recorded in the lock directory
// (base/owner_lock.hpp lock_dir()) as "alias-ALSO" holding "PID\nKEY\n", removed when it dies (if
// still its own). Error(Exit::file) when it cannot be written, or when a live record of another kscfg
// already names `also` or `key`, or stands for `also` (another listener of one of these keys).
class CouplerAlias {
 public:
  CouplerAlias(const std::string& also, const std::string& key);
  ~CouplerAlias();
  CouplerAlias(const CouplerAlias&) = delete;
  CouplerAlias& operator=(const CouplerAlias&) = delete;

 private:
  std::string path_;
};

// The station behind a Modbus coupler at its unit id (scan caches and session journals are kept
// per unit, decision 24): "ip-10.0.3.11-unit1", "rtu-_dev_ttyUSB0-unit3".
std::string station_key(const ModbusTarget& target);
// The session journals of direct register access over ADS (their entries are of another kind than
// a Modbus session's, docs/design.md 6.2): "ip-10.0.3.11-ads".
std::string station_key(const AdsTarget& target);
// A CANopen node is one station and reached one way (SDO): its coupler key, "can-can0-n3".
std::string station_key(const CanTarget& target);

}  // namespace kscfg
