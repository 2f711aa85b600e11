// Serving the emulated station (kscfg serve) over Modbus TCP or RTU, ADS and CANopen, one of them
// or several at once: the servers of the protocols given, their options and what they counted.
#pragma once
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/emulator/ads_server.hpp"
#include "kscfg/emulator/can_server.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/modbus_server.hpp"

namespace kscfg {

// The options of each protocol served and, once served, what each server counted.
struct Servers {
  std::optional<ServeOptions> so;
  std::optional<AdsServeOptions> ao;
  std::optional<CanServeOptions> co;
  std::optional<ServeStats> st;
  std::optional<AdsServeStats> at;
  std::optional<CanServeStats> ct;
};

// Saves the state's text (durable: the servers save soon after every change).
using SaveStateText = std::function<void(const std::string&)>;
// Called with the servers' URIs once they listen (the first protocol's first).
using Listening = std::function<void(const std::vector<std::string>&)>;

// Serves `station` over every protocol of `s` until `stop` says so: one server alone, or several
// sharing one station, one K-bus and one saver in one poll loop, the kscfg clients of this computer
// over any of them taking one coupler lock (a protocol whose clients cannot be named from here is
// warned about). What each server counted is left in `s`. Error(usage) for --tcp and --ads on two
// addresses.
void serve_station(EmulatedStation& station, const SaveStateText& save, const Listening& listening,
                   const std::function<bool()>& stop, Servers& s);

// A Modbus RTU line to serve on: DEVICE[?baud=..&parity=..&data=..&stop=..&unit=..]. Error(usage)
// as for an rtu: port.
void set_rtu_line(ServeOptions& so, const std::string& device);
// Whether a CAN URI names its node itself (?node=).
bool can_uri_names_node(const std::string& uri);
// An AMS NetId given for option `opt`; Error(usage) naming it.
ams::NetId netid_option(const char* opt, const std::string& v);
// The protocol a served URI speaks: "modbus", "ads" or "can".
const char* served_protocol(const std::string& uri);

}  // namespace kscfg
