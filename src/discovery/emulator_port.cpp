// The emulator's port (emu, emu:PATH, emu:mem): the emulated station behind an EmulatorLink, its
// registers through the process-image handshake as on a Modbus coupler, its state file saved at
// the end of a run.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/serial_model.hpp"
#include "kscfg/session/handshake.hpp"
#include "ports.hpp"

namespace kscfg {

namespace {

// The emulator's station: the emulated coupler lays its image out itself, and tells it.
class EmulatorDiscovery : public StationDiscovery {
 public:
  explicit EmulatorDiscovery(EmulatedStation& station) : station_(station) {}
  const StationLayout* layout_upto(unsigned) override { return &station_.layout(); }
  const StationSpec* station() override { return &station_.spec(); }
  bool lays_out_itself() const override { return true; }

 private:
  EmulatedStation& station_;
};

class EmulatorPort : public Port {
 public:
  EmulatorPort(std::string uri, const std::string& path, const Catalog& catalog, const LinkOptions& opt)
      : uri_(std::move(uri)), store_(path, catalog, opt.lock_wait), link_(store_) {
    access_ = std::make_unique<HandshakeAccess>(link_, handshake_options(port_session(opt)));
    engine_ = std::make_unique<Engine>(*access_);
    discovery_ = std::make_unique<EmulatorDiscovery>(store_.station());
  }
  ~EmulatorPort() override { close_before_link(); }

  std::string describe() const override { return link_.describe(); }
  Link& image() override { return link_; }
  std::size_t exchanges() const override { return link_.exchanges(); }

  CouplerSettings coupler_settings(unsigned) override {
    throw Error(
        Exit::usage, fmt::format("'kscfg coupler' reads a coupler's settings; '{}' is the emulator", describe()),
        "serve it and read those: kscfg serve --tcp 127.0.0.1:5020 (or --ads), then --port tcp://... or ads://...");
  }
  PortScan scan(const Catalog&, const SessionOptions&, const PortScanRequest&) override {
    // The embedded emulator is no coupler on a bus: nothing to discover, kscfg holds its station.
    throw Error(Exit::usage,
                fmt::format("'kscfg scan' discovers a Modbus, ADS or CANopen coupler; the port '{}' is the "
                            "emulator, whose station needs no scan",
                            uri_),
                "'kscfg info' shows its terminals; 'kscfg station init --from-port FILE' writes them as a "
                "station file");
  }
  void recover_dead_sessions(const Catalog& catalog, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned)>& layout_upto) override {
    recover_image_sessions(*engine_, link_, catalog, so, layout_upto);
  }
  void commit() override { store_.save(); }

  void let_time_pass(std::chrono::microseconds t) override {
    EmulatedStation& st = store_.station();
    auto cycles = std::min<long long>(t.count() / std::max(1u, st.kbus_cycle_us), 100000);
    for (long long i = 0; i < cycles; ++i) st.cycle();
  }
  std::string far_end(unsigned position, unsigned channel) override {
    EmulatedStation& st = store_.station();
    if (st.has_channel(position, channel))
      if (auto* ser = st.channel(position, channel).serial()) return ser->far_end_description();
    return {};
  }
  std::string restart_hint() const override { return "'kscfg emu restart'"; }
  EmulatedStation* emulated() override { return &store_.station(); }

 private:
  std::string uri_;      // as the user named it
  EmulatorStore store_;  // the state file and station the link moves the image of: before it
  EmulatorLink link_;
};

}  // namespace

std::unique_ptr<Port> open_emulator_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                         const LinkOptions& opt) {
  return std::make_unique<EmulatorPort>(uri, p.target.empty() ? EmulatorStore::default_path() : p.target, catalog, opt);
}

}  // namespace kscfg
