#include "kscfg/emulator/emulator.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/station/map.hpp"
#include "state_schema.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// ChannelModel

ChannelModel::ChannelModel(const TerminalType& type, std::array<std::uint16_t, proto::kRegisterCount> regs)
    : type_(&type), regs_(regs) {
  // ROM is what the factory burnt in, whatever a state file says.
  for (unsigned r = 8; r < 15; ++r) regs_[r] = type.regs[r].def;
  if (type.is_serial()) serial_ = std::make_unique<SerialModel>(type);
  if (type.family == "encoder" && type.r8 == 5101) encoder_ = std::make_unique<EncoderModel>(type);
  if (AnalogModel::applies(type)) analog_ = std::make_unique<AnalogModel>(type);
}

std::uint16_t ChannelModel::read_register(unsigned r) const {
  if (r >= proto::kRegisterCount || !proto::is_implemented(r)) return 0;
  if (r == proto::kCodeWordRegister) return unlocked() ? proto::kCodeWord : 0;
  return regs_[r];
}

void ChannelModel::factory_reset() {
  // The factory values; a value set per terminal at the factory (`typical`, calibration) stays.
  auto d = type_->defaults();
  for (unsigned r = 16; r < 48; ++r)
    if (r != proto::kCodeWordRegister && type_->regs[r].storage == proto::Storage::seerom && !type_->regs[r].typical)
      regs_[r] = d[r];
}

void ChannelModel::power_cycle() {
  regs_[proto::kCodeWordRegister] = 0;  // RAM: write protection is on again
  reg_mode_ = false;
  req_ctrl_ = 0;
  req_value_ = 0;
  req_seen_ = 0;
  executed_ = false;
  if (serial_) serial_->power_cycle();
  if (encoder_) encoder_->power_cycle();
  if (analog_) analog_->power_cycle();
}

void ChannelModel::write_register(unsigned r, std::uint16_t v) {
  if (r >= proto::kRegisterCount || !proto::is_implemented(r)) return;  // not implemented: ignored
  if (faults.ignore_writes.count(r)) return;
  if (r == proto::kCodeWordRegister) {
    regs_[r] = v;  // any other value sets write protection
    return;
  }
  const RegisterDef& def = type_->regs[r];
  if (!def.writable || def.storage == proto::Storage::rom) return;  // ROM and read-only: ignored
  if (proto::is_protected(r) && !unlocked()) return;                // needs the code word
  if (r == proto::kCommandRegister) {
    // R7: command register. 0x7000 restores factory settings where the manual documents it.
    if (type_->reset == FactoryReset::r7 && v == proto::kFactoryResetCommand && unlocked()) factory_reset();
    regs_[r] = v;
    return;
  }
  regs_[r] = v;
}

void ChannelModel::cycle(std::uint64_t n, std::span<const std::uint8_t> out, std::span<std::uint8_t> in, int vi,
                         unsigned delay, double cycle_us) {
  std::uint8_t ctrl = out.empty() ? 0 : out[0];
  auto vidx = static_cast<std::size_t>(vi);
  if (serial_) {
    // The serial line runs whatever the K-bus mode; R0, R1 and R6 follow the FIFOs.
    serial_->mute = faults.mute;
    serial_->run_line(cycle_us, regs_);
  }
  if (encoder_) encoder_->run(cycle_us, regs_);  // the encoder turns and the counter counts in any mode
  auto serial_registers = [&] {
    if (!serial_) return;
    regs_[0] = serial_->tx_count();
    regs_[1] = serial_->rx_count();
    regs_[6] = serial_->diagnostics();
  };
  if (!(ctrl & proto::kReg) || !type_->has_registers) {
    // Process-data mode: the plain terminal model has no process data of its own; a serial
    // terminal runs its handshake (serial_model.hpp).
    if (reg_mode_) std::fill(in.begin(), in.end(), 0);
    reg_mode_ = false;
    if (serial_) serial_->handshake(out, in, regs_);
    if (encoder_) encoder_->process_data(out, in, regs_);
    if (analog_) analog_->process_data(out, in, vidx, regs_);
    serial_registers();
    return;
  }
  serial_registers();
  std::uint16_t value = 0;
  if (out.size() > vidx + 1) value = static_cast<std::uint16_t>(out[vidx] | (out[vidx + 1] << 8));
  bool write = (ctrl & proto::kWrite) != 0;
  if (!reg_mode_ || ctrl != req_ctrl_ || (write && value != req_value_)) {
    reg_mode_ = true;
    req_ctrl_ = ctrl;
    req_value_ = value;
    req_seen_ = n;
    executed_ = false;
  }
  if (faults.mute || n < req_seen_ + delay) return;  // not answered yet: the status stays stale
  unsigned addr = ctrl & proto::kAddrMask;
  if (write && !executed_) write_register(addr, value);
  executed_ = true;
  std::uint16_t answer = write ? 0 : read_register(addr);
  if (!in.empty()) in[0] = static_cast<std::uint8_t>(proto::kReg | addr);  // as the seed's example: 0xDF -> 0x9F
  if (in.size() > vidx + 1) {
    in[vidx] = static_cast<std::uint8_t>(answer & 0xFF);
    in[vidx + 1] = static_cast<std::uint8_t>(answer >> 8);
  }
}

// ---------------------------------------------------------------------------------------------
// EmulatedStation

bool EmulatedStation::has_model(const TerminalType& type) {
  // Terminals with registers answer in register mode; serial devices without registers (the CX
  // interface in KL6xx1 mode) still run their handshake. Digital, power and end terminals have no
  // model: their bytes are the image's.
  return type.has_registers || type.is_serial();
}

EmulatedStation::EmulatedStation(const StationSpec& spec, const Catalog& catalog) : spec_(spec), catalog_(&catalog) {
  for (std::size_t i = 0; i < spec_.terminals.size(); ++i) {
    const auto& ts = spec_.terminals[i];
    const TerminalType& type = catalog.get(ts.type);
    if (!has_model(type)) continue;
    for (unsigned ch = 0; ch < type.channels; ++ch)
      slots_.push_back(
          {static_cast<unsigned>(i + 1), ch, ChannelModel(type, channel_registers(type, &ts, ch)), {}, {}});
  }
  // Settings of the file now live in the terminals' registers; the spec keeps the composition.
  for (auto& t : spec_.terminals) t.channels.clear();
  for (auto& s : slots_) s.at_start = s.model.registers();
  lay_out();
}

void EmulatedStation::restart() {
  for (auto& s : slots_) {
    s.model.power_cycle();
    s.at_start = s.model.registers();
  }
  lay_out();  // outputs and inputs cleared, as a coupler starts
}

void EmulatedStation::lay_out() {
  layout_ = compute_layout(spec_, *catalog_, spec_.settings(), [&](unsigned pos, unsigned ch) {
    for (const auto& s : slots_)
      if (s.position == pos && s.channel == ch) return s.at_start;
    return catalog_->get(spec_.terminals.at(pos - 1).type).defaults();
  });
  out_.assign(layout_.out_bytes, 0);
  in_.assign(layout_.in_bytes, 0);
  for (auto& s : slots_) {
    const auto& t = layout_.terminal(s.position);
    s.in_struct.assign(t.complex && s.channel < t.channels.size() ? t.channels[s.channel].in_struct : 0, 0);
    if (auto* ser = s.model.serial(); ser && t.complex && s.channel < t.channels.size())
      ser->attach(t.channels[s.channel], t.format);
  }
}

bool EmulatedStation::has_channel(unsigned position, unsigned ch) const {
  for (const auto& s : slots_)
    if (s.position == position && s.channel == ch) return true;
  return false;
}

ChannelModel& EmulatedStation::channel(unsigned position, unsigned ch) {
  for (auto& s : slots_)
    if (s.position == position && s.channel == ch) return s.model;
  throw Error(Exit::usage, fmt::format("no register channel {} at position {}", ch + 1, position));
}

void EmulatedStation::cycle() {
  ++cycle_;
  std::vector<std::uint8_t> out_struct;
  for (auto& s : slots_) {
    const TerminalImage& t = layout_.terminals.at(s.position - 1);
    if (!t.complex || s.channel >= t.channels.size()) continue;
    const ChannelImage& ci = t.channels[s.channel];
    out_struct.assign(ci.out_struct, 0);
    for (const auto& b : ci.out)
      if (b.index >= 0 && static_cast<std::size_t>(b.index) < out_struct.size()) out_struct[b.index] = out_[b.offset];
    s.model.cycle(cycle_, out_struct, s.in_struct, ci.value_index, response_delay, kbus_cycle_us);
    for (const auto& b : ci.in)
      if (b.index >= 0 && static_cast<std::size_t>(b.index) < s.in_struct.size()) in_[b.offset] = s.in_struct[b.index];
  }
}

nlohmann::json EmulatedStation::to_json() const {
  nlohmann::json j;
  j["format"] = "kscfg-emulator";
  j["version"] = 1;
  j["station"] = station_to_toml(spec_);
  j["response_delay"] = response_delay;
  if (kbus_cycle_us != 1000) j["kbus_cycle_us"] = kbus_cycle_us;
  nlohmann::json chans = nlohmann::json::array();
  for (const auto& s : slots_) {
    nlohmann::json c;
    c["position"] = s.position;
    c["channel"] = s.channel;
    c["type"] = spec_.terminals.at(s.position - 1).type;
    c["registers"] = s.model.registers();
    // Registers written since the coupler's last start (R35, ...) have not laid out its image yet.
    if (s.at_start != s.model.registers()) c["start_registers"] = s.at_start;
    if (!s.model.faults.ignore_writes.empty()) c["ignore_writes"] = s.model.faults.ignore_writes;
    if (s.model.faults.mute) c["mute"] = true;
    if (const auto* ser = s.model.serial()) c["serial"] = ser->to_json();
    if (const auto* enc = s.model.encoder()) c["encoder"] = enc->to_json();
    if (const auto* an = s.model.analog(); an && !an->to_json().empty()) c["analog"] = an->to_json();
    chans.push_back(c);
  }
  j["channels"] = chans;
  std::string hex;
  for (auto b : out_) hex += fmt::format("{:02x}", b);
  j["outputs"] = hex;
  return j;
}

std::unique_ptr<EmulatedStation> EmulatedStation::from_json(const nlohmann::json& j, const Catalog& catalog) {
  auto bad = [](const std::string& why) -> Error { return Error(Exit::file, why); };
  try {
    if (!j.is_object() || !j.contains("format") || j["format"] != "kscfg-emulator")
      throw bad("not a kscfg emulator state");
    if (j.contains("version") && j["version"] != 1) throw bad("unsupported state version");
    validate_state(j);  // every entry's type and range (state_schema.cpp)
    StationSpec spec = parse_station(j.at("station").get<std::string>(), "state:station", catalog);
    auto st = std::make_unique<EmulatedStation>(spec, catalog);
    st->response_delay = j.value("response_delay", 1u);
    if (st->response_delay > 1000) throw bad("response_delay out of range");
    st->kbus_cycle_us = j.value("kbus_cycle_us", 1000u);
    if (st->kbus_cycle_us == 0 || st->kbus_cycle_us > 1000000) throw bad("kbus_cycle_us out of range");
    const auto& chans = j.at("channels");
    if (!chans.is_array() || chans.size() != st->slots_.size()) throw bad("channel list does not match the station");
    for (std::size_t i = 0; i < chans.size(); ++i) {
      auto& slot = st->slots_[i];
      const auto& c = chans[i];
      if (c.at("position").get<unsigned>() != slot.position || c.at("channel").get<unsigned>() != slot.channel ||
          c.at("type").get<std::string>() != spec.terminals.at(slot.position - 1).type)
        throw bad(fmt::format("channel {} does not match the station", i));
      auto registers = [&](const char* key) {
        auto regs = c.at(key).get<std::vector<unsigned>>();
        if (regs.size() != proto::kRegisterCount) throw bad("a register set must have 64 values");
        std::array<std::uint16_t, proto::kRegisterCount> r{};
        for (unsigned k = 0; k < proto::kRegisterCount; ++k) {
          if (regs[k] > 0xFFFF) throw bad("register value out of range");
          r[k] = static_cast<std::uint16_t>(regs[k]);
        }
        return r;
      };
      slot.model = ChannelModel(catalog.get(spec.terminals.at(slot.position - 1).type), registers("registers"));
      slot.at_start = slot.model.registers();
      if (c.contains("start_registers")) {
        auto r = registers("start_registers");
        for (unsigned k = 8; k < 15; ++k) r[k] = slot.at_start[k];  // ROM, as ChannelModel keeps it
        slot.at_start = r;
      }
      if (c.contains("ignore_writes"))
        slot.model.faults.ignore_writes = c.at("ignore_writes").get<std::set<unsigned>>();
      slot.model.faults.mute = c.value("mute", false);
      if (auto* ser = slot.model.serial(); ser && c.contains("serial")) ser->from_json(c.at("serial"));
      if (auto* enc = slot.model.encoder(); enc && c.contains("encoder")) enc->from_json(c.at("encoder"));
      if (auto* an = slot.model.analog(); an && c.contains("analog")) an->from_json(c.at("analog"));
    }
    // The image the coupler laid out at its last start, from the registers it read then (a state
    // without start_registers: from the registers as they are, as before they were kept).
    st->lay_out();
    auto hex = j.at("outputs").get<std::string>();
    // Outputs of another size: a state written before start_registers were kept, after a new R35
    // (its image was laid out anew at every load); they start cleared, as at a coupler's start.
    if (hex.size() == st->out_.size() * 2) {
      for (std::size_t i = 0; i < st->out_.size(); ++i)
        st->out_[i] = static_cast<std::uint8_t>(std::stoul(hex.substr(2 * i, 2), nullptr, 16));
    }
    return st;
  } catch (const Error& e) {
    // The station inside a state is part of the file: a type the catalog does not know or an
    // image the coupler refuses is a corrupt state (Exit::file), not a usage error.
    if (e.code() == Exit::file) throw;
    throw bad(e.what());
  } catch (const std::exception& e) {
    throw bad(e.what());
  }
}

// ---------------------------------------------------------------------------------------------
// EmulatorStore

std::string EmulatorStore::default_path() { return (std::filesystem::path(state_dir()) / "emulator.json").string(); }

namespace {

// Where a `kscfg serve` of a state file says where it serves it: "PID\nURI\n" (a line per URI:
// serve --tcp --ads has two), beside the file
// (the end of its links, as the lock), written after the lock is taken and removed before it goes.
std::string serve_record_path(const std::string& state) { return resolve_link(state) + ".serve"; }

// The directory a state file goes in. The default location's is made (the first run of kscfg on
// this computer); one given with emu:PATH must exist: a typo in it would otherwise make directories
// and a fresh station there, and every command would go on as if it were the station meant.
void check_state_directory(const std::string& path) {
  auto dir = std::filesystem::path(path).parent_path();
  if (dir.empty()) return;
  std::error_code ec;
  if (path == EmulatorStore::default_path()) {
    std::filesystem::create_directories(dir, ec);
    if (ec)
      throw Error(Exit::file, fmt::format("cannot create the state directory '{}': {}", dir.string(), ec.message()));
    return;
  }
  if (std::filesystem::is_directory(dir, ec)) return;
  bool missing = !std::filesystem::exists(std::filesystem::symlink_status(dir, ec));
  throw Error(Exit::file,
              fmt::format("the directory of the emulator state file '{}' {}", path,
                          missing ? "does not exist" : "is not a directory"),
              "check the path, or make the directory first: kscfg makes only the default state's (--port emu)");
}

// The state file's lock, taken as the store and `emu reset` take it. A file held by a running serve
// is refused at once, naming the serve and the URI that reaches the same station through it: the
// serve holds the file as long as it runs, so waiting for it is waiting for an operator.
OwnerLock lock_state_file(const std::string& path, const LockWait& wait) {
  std::string lock_path = resolve_link(path) + ".lock";
  std::string record = serve_record_path(path);
  RegularFile r = read_regular_file(record, "serve record", 1024);
  if (r.exists && r.refused.empty()) {
    std::vector<std::string> lines;
    for (std::size_t at = 0; at < r.text.size() && lines.size() < 4;) {
      auto nl = r.text.find('\n', at);
      if (nl == std::string::npos) nl = r.text.size();
      lines.push_back(r.text.substr(at, nl - at));
      at = nl + 1;
    }
    std::string pid = lines.empty() ? "" : lines[0];
    std::vector<std::string> uris(lines.begin() + (lines.empty() ? 0 : 1), lines.end());
    bool sane = !pid.empty() && pid.size() < 12 && !uris.empty() &&
                std::all_of(pid.begin(), pid.end(), [](char c) { return c >= '0' && c <= '9'; });
    for (const auto& u : uris)
      sane = sane && !u.empty() && u.size() < 300 &&
             std::all_of(u.begin(), u.end(), [](char c) { return c > ' ' && c < 0x7F; });
    std::string uri = sane ? fmt::format("{}", fmt::join(uris, " and ")) : "";
    // An slcan URI names the serve's own end of a serial line (a pseudo-terminal pair's): a client
    // opens the other end, which the serve does not know; -p with the serve's end is refused "in use".
    std::vector<std::string> reach, lines_served;
    for (const auto& u : uris) (u.rfind("slcan:", 0) == 0 ? lines_served : reach).push_back(u);
    std::vector<std::string> ways;
    if (!reach.empty()) ways.push_back(fmt::format("through it with -p {}", fmt::join(reach, " or -p ")));
    if (!lines_served.empty())
      ways.push_back(fmt::format("through the other end of the serial line it plays an slcan adapter on ({})",
                                 fmt::join(lines_served, ", ")));
    auto holder = sane ? OwnerLock::holder(lock_path) : std::nullopt;
    if (holder && std::to_string(holder->pid) == pid)
      throw Error(Exit::busy,
                  fmt::format("the emulator state file {} is held by kscfg serve (process {}), which serves it at {}",
                              path, pid, uri),
                  fmt::format("reach the same station {}, or stop the serve", fmt::join(ways, ", or ")));
  }
  OwnerLock lock = OwnerLock::acquire(lock_path, fmt::format("the emulator state file {}", path), wait);
  // A record left by a serve that was killed (-9): nobody serves the file now.
  if (r.exists) ::unlink(record.c_str());
  return lock;
}

}  // namespace

void EmulatorStore::announce(const std::vector<std::string>& uris) {
  if (path_.empty() || !lock_.held() || uris.empty()) return;
  std::string record = serve_record_path(path_);
  write_file_atomic(record, fmt::format("{}\n{}\n", ::getpid(), fmt::join(uris, "\n")), true);
  announced_ = record;
}

EmulatorStore::EmulatorStore(std::string path, const Catalog& catalog, const LockWait& wait) : path_(std::move(path)) {
  if (path_.empty() || path_ == "mem") {
    path_.clear();
    station_ = std::make_unique<EmulatedStation>(default_station(), catalog);
    return;
  }
  check_state_directory(path_);
  // Beside the file a symbolic link points to, so that every name of it takes the same lock.
  lock_ = lock_state_file(path_, wait);
  remove_stale_temporaries(path_);  // what a killed kscfg left, also when this run only reads
  struct stat st {};
  if (::stat(path_.c_str(), &st) != 0 && errno == ENOENT) {
    station_ = std::make_unique<EmulatedStation>(default_station(), catalog);
    return;
  }
  std::string text;
  try {
    text = read_input_file(path_, "the emulator state file");
  } catch (...) {
    lock_.release();
    throw;
  }
  try {
    auto j = nlohmann::json::parse(text);
    station_ = EmulatedStation::from_json(j, catalog);
    saved_ = snapshot();
  } catch (const std::exception& e) {
    lock_.release();
    std::string why = e.what();
    if (auto p = why.find('\n'); p != std::string::npos) why.resize(p);
    throw Error(Exit::file, fmt::format("emulator state file '{}' is corrupt ({})", path_, why),
                "run 'kscfg emu reset' to restore the factory state (the file is left as it is)");
  }
}

EmulatorStore::~EmulatorStore() {
  if (!announced_.empty()) ::unlink(announced_.c_str());  // before the lock goes
}

std::string EmulatorStore::snapshot() const { return station_->to_json().dump(1) + "\n"; }

bool EmulatorStore::save() { return save_text(snapshot()); }

bool EmulatorStore::save_text(const std::string& text) {
  if (path_.empty() || text == saved_) return false;
  write_file_atomic(path_, text);
  saved_ = text;
  return true;
}

// ---------------------------------------------------------------------------------------------
// EmulatorLink

EmulatorLink::EmulatorLink(EmulatorStore& store) : store_(&store), station_(&store.station()) {}

EmulatorLink::EmulatorLink(EmulatedStation& station) : station_(&station) {}

std::string EmulatorLink::describe() const {
  if (store_ && !store_->path().empty()) return "emu:" + store_->path();
  return "emu:mem";
}

static void check_range(std::size_t offset, std::size_t n, std::size_t size, const char* what) {
  if (offset + n > size)
    throw Error(Exit::link, fmt::format("{} image access {}..{} beyond its {} bytes", what, offset, offset + n, size));
}

void EmulatorLink::read_inputs(std::size_t offset, std::span<std::uint8_t> dst) {
  ++exchanges_;
  station_->cycle();  // the K-bus runs between two reads of the image
  const auto& in = station_->inputs();
  check_range(offset, dst.size(), in.size(), "input");
  std::copy_n(in.begin() + static_cast<std::ptrdiff_t>(offset), dst.size(), dst.begin());
}

void EmulatorLink::read_outputs(std::size_t offset, std::span<std::uint8_t> dst) {
  ++exchanges_;
  const auto& out = station_->outputs();
  check_range(offset, dst.size(), out.size(), "output");
  std::copy_n(out.begin() + static_cast<std::ptrdiff_t>(offset), dst.size(), dst.begin());
}

void EmulatorLink::write_outputs(std::size_t offset, std::span<const std::uint8_t> src) {
  ++exchanges_;
  auto& out = station_->outputs();
  check_range(offset, src.size(), out.size(), "output");
  std::copy(src.begin(), src.end(), out.begin() + static_cast<std::ptrdiff_t>(offset));
}

std::chrono::microseconds EmulatorLink::poll_gap(unsigned poll_number) const {
  // The emulated K-bus runs on every read; only a terminal that does not answer makes the
  // caller poll long, and then there is no need to spin.
  return std::chrono::microseconds(poll_number > 64 ? 200 : 0);
}

}  // namespace kscfg

namespace kscfg {

EmulatorRestart restart_emulator_state(const std::string& path, const Catalog& catalog, const LockWait& wait) {
  EmulatorStore store(path, catalog, wait);
  EmulatedStation& st = store.station();
  StationLayout before = st.layout();
  st.restart();
  const StationLayout& after = st.layout();
  EmulatorRestart r{before.in_bytes, before.out_bytes, after.in_bytes, after.out_bytes, {}};
  for (std::size_t i = 0; i < after.terminals.size() && i < before.terminals.size(); ++i) {
    const auto &x = before.terminals[i], &y = after.terminals[i];
    auto in = [](const TerminalImage& t) { return t.complex ? t.in_size : t.bits_in; };
    auto out = [](const TerminalImage& t) { return t.complex ? t.out_size : t.bits_out; };
    if (!in(x) && !out(x) && !in(y) && !out(y)) continue;  // no image (end, power terminals)
    if (x.format != y.format || x.in_offset != y.in_offset || x.in_size != y.in_size || x.out_offset != y.out_offset ||
        x.out_size != y.out_size || x.in_bit != y.in_bit || x.out_bit != y.out_bit)
      r.changed.push_back({y.position, y.type->type, x.format, y.format, in(x), out(x), in(y), out(y), !y.complex});
  }
  store.save();
  return r;
}

void reset_emulator_state(const std::string& path, const StationSpec& spec, const Catalog& catalog,
                          const LockWait& wait) {
  EmulatedStation fresh(spec, catalog);
  // The coupler's limits, as `map` applies them (a Modbus coupler's register map holds 512 bytes).
  check_image_limits(fresh.layout(), coupler_profile(spec.coupler));
  if (path.empty() || path == "mem") return;
  check_state_directory(path);
  OwnerLock lock = lock_state_file(path, wait);
  write_file_atomic(path, fresh.to_json().dump(1) + "\n");
}

}  // namespace kscfg
