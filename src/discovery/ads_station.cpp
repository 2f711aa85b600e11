// The station behind an ADS coupler, and `kscfg scan` over ADS port 100 (discovery/ads_station.hpp,
// docs/transports/ads.md).
#include "kscfg/discovery/ads_station.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <set>

#include "kscfg/discovery/ads_image.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

namespace {

// ADS results that mean "the coupler does not have this" rather than a failure of the link.
constexpr std::uint32_t kNotSupported = 0x701, kNoGroup = 0x702, kNoOffset = 0x703, kDenied = 0x704, kBadSize = 0x705;
bool not_served(std::uint32_t result) {
  return result == kNotSupported || result == kNoGroup || result == kNoOffset || result == kDenied ||
         result == kBadSize;
}

AdsClient::Call table_call(unsigned table, unsigned reg, unsigned timeout_ms) {
  AdsClient::Call c;
  c.port = adsport::kRegisters;
  c.command = ams::kRead;
  c.data = ams::read_request(adsreg::kCouplerGroup, adsreg::table_offset(table, reg), 2);
  c.timeout_ms = std::max(timeout_ms, adsreg::kMinRegisterTimeoutMs);
  c.what = fmt::format("reading coupler table {} register {}", table, reg);
  return c;
}

std::optional<std::uint16_t> value_of(const AdsClient::Reply& r) {
  if (r.result != 0 || r.data.size() != 2) return std::nullopt;
  return ams::get16(r.data.data());
}

// Table 9 of the coupler: register 0 and the terminals, or nothing when the coupler does not serve
// it. Register 0 and the first 64 entries in one batch, the rest only when those are all taken.
std::optional<std::vector<std::uint16_t>> read_table9(AdsClient& client, unsigned timeout_ms) {
  std::vector<std::uint16_t> regs;
  for (unsigned first = 0, count = 65; first <= adsreg::kMaxTerminals; first += count, count = 64) {
    count = std::min(count, adsreg::kMaxTerminals + 1 - first);
    std::vector<AdsClient::Call> calls;
    for (unsigned r = first; r < first + count; ++r) calls.push_back(table_call(adsreg::kTable9, r, timeout_ms));
    auto replies = client.transact(calls);
    for (std::size_t i = 0; i < replies.size(); ++i) {
      if (replies[i].result != 0 && not_served(replies[i].result) && first + i == 0) return std::nullopt;
      if (replies[i].result != 0) throw client.ads_error(replies[i].result, adsport::kRegisters, calls[i].what);
      auto v = value_of(replies[i]);
      if (!v)
        throw Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of 2", client.target().where(),
                                            calls[i].what, replies[i].data.size()));
      if (first + i > 0 && *v == 0) return regs;
      regs.push_back(*v);
    }
  }
  return regs;
}

// ReadDeviceInfo on port 100 (name and version) into r.ident. An ADS result other than 0 leaves
// it unknown, as a Modbus coupler that refuses 0x1000..0x1006.
void read_device_info(AdsClient& client, ScanResult& r) {
  AdsClient::Call c{.port = adsport::kRegisters, .command = ams::kReadDeviceInfo, .data = {}, .what = "ReadDeviceInfo"};
  AdsClient::Reply rep;
  try {
    rep = client.call(c);
  } catch (const Error& e) {
    // An AMS error for the command itself (0x8, as a BK9050 answers ReadState): unknown. A
    // failure of the link shows again at the next request, which table 9 makes.
    if (e.code() == Exit::interrupted) throw;
    rep.result = 0x701;
  }
  if (rep.result == 0 && rep.data.size() >= 4) {
    std::string name;
    for (std::size_t i = 4; i < rep.data.size() && rep.data[i]; ++i)
      name += (rep.data[i] >= 0x20 && rep.data[i] < 0x7F) ? static_cast<char>(rep.data[i]) : '?';
    r.ident = fmt::format("{} {}.{}.{}", name, rep.data[0], rep.data[1], ams::get16(rep.data.data() + 2));
    r.ident_read = true;
  }
}

// Table 9 over port 100 (discovery/table9.hpp), and a walk by terminal number where the coupler does
// not serve it.
class AdsReader final : public Table9Reader {
 public:
  // `check_image`, `memo`, `cancel`: AdsScanOptions'.
  AdsReader(AdsClient& client, unsigned timeout_ms, bool check_image, SilentMemo memo, const CancelToken* cancel)
      : client_(client),
        timeout_ms_(timeout_ms),
        access_(client, timeout_ms),
        check_image_(check_image),
        memo_(std::move(memo)),
        cancel_(cancel) {}

  Words words() const override {
    return {"ads", fmt::format("reading coupler at {}", client_.target().where()), "a number on port 100", false};
  }
  void identify(ScanResult& r, const Table9ScanOptions& opt) override {
    if (opt.check) read_device_info(client_, r);
  }
  Table9Station terminals(const Catalog& catalog, ScanResult& r, const Table9ScanOptions& opt) override {
    step(opt, "table 9 (its terminal list)");
    auto t9 = read_table9(client_, timeout_ms_);
    // Table 100 registers 15 and 26: whether the coupler serves Modbus TCP, and on which port; there
    // it reports its image lengths, which confirm or contradict the layout (discovery/ads_image.hpp).
    CouplerImage image = check_image_ ? read_image(opt) : CouplerImage{};
    Table9Station st = t9 ? table9_station(catalog, *t9, r) : walk(catalog, r, image, opt);
    st.image = std::move(image);
    return st;
  }
  const CouplerProfile& profile(ScanResult& r, const Table9Station& st) override;
  std::vector<TerminalRegisters> registers(const std::vector<TerminalRead>& reads, ScanResult& r,
                                           const Table9ScanOptions& opt) override;
  std::uint16_t r8_without_registers(const TerminalType&) const override { return 0; }
  void finish(ScanResult& r, const Table9Station& st, const Catalog& catalog, const RegisterSource& regs) override {
    if (!check_image_ || st.incomplete) return;
    judge_image(r.layout, st.image, r.spec, catalog, regs,
                st.from_table9 ? "the station from table 9" : "the station walked by terminal number");
    if (!r.layout.image_refused.empty()) {
      r.matches = false;
      r.notes.push_back(r.layout.image_refused);
    } else if (!r.layout.image_unconfirmed.empty()) {
      r.notes.push_back(r.layout.image_unconfirmed);
    }
  }
  // A station file's layout against the coupler's image lengths.
  void check_file(StationLayout& L, const StationSpec& spec, const Table9Scan& found, const Catalog& catalog,
                  const std::string& origin) override {
    judge_image(
        L, found.image, spec, catalog,
        [&](unsigned pos, unsigned ch) {
          const TerminalSpec& ts = spec.terminals.at(pos - 1);
          return channel_registers(catalog.get(ts.type), &ts, ch);
        },
        origin);
  }

 private:
  static void step(const Table9ScanOptions& opt, const std::string& what) {
    if (opt.status) opt.status(what);
  }
  CouplerImage read_image(const Table9ScanOptions& opt);
  Table9Station walk(const Catalog& catalog, ScanResult& r, const CouplerImage& image, const Table9ScanOptions& opt);
  unsigned walk_numbers(const Catalog& catalog, bool no_digital, Table9Station& st, std::vector<unsigned>& none);

  AdsClient& client_;
  unsigned timeout_ms_;
  adsreg::RegisterAccess access_;
  bool check_image_;
  SilentMemo memo_;
  const CancelToken* cancel_;
};

CouplerImage AdsReader::read_image(const Table9ScanOptions& opt) {
  step(opt, "the image lengths");
  std::vector<AdsClient::Call> t100{table_call(adsreg::kTable100, 15, timeout_ms_),
                                    table_call(adsreg::kTable100, 26, timeout_ms_)};
  auto rep = client_.transact(t100);
  std::optional<std::uint16_t> r15, r26;
  for (std::size_t i = 0; i < rep.size(); ++i) {
    if (rep[i].result != 0 && not_served(rep[i].result)) continue;
    if (auto e = access_.reply_error(rep[i], t100[i], true)) throw *e;
    (i == 0 ? r15 : r26) = ams::get16(rep[i].data.data());
  }
  return read_coupler_image(client_.target(), r15, r26, timeout_ms_, opt.trace, cancel_, memo_);
}

// R8 of every terminal number, 16 in flight at a time, into st.terminals; the numbers that answered
// without registers into `none`. The last number with registers.
unsigned AdsReader::walk_numbers(const Catalog& catalog, bool no_digital, Table9Station& st,
                                 std::vector<unsigned>& none) {
  unsigned last = 0;
  bool end = false;
  for (unsigned first = 1; !end && first <= adsreg::kMaxTerminals; first += 16) {
    std::vector<AdsClient::Call> calls;
    for (unsigned n = first; n < first + 16 && n <= adsreg::kMaxTerminals; ++n)
      calls.push_back(access_.read_call({n, 0, 8}));
    auto replies = client_.transact(calls);
    for (std::size_t i = 0; i < replies.size() && !end; ++i) {
      unsigned n = first + static_cast<unsigned>(i);
      if (replies[i].result != 0 && not_served(replies[i].result)) {
        none.push_back(n);
        end = no_digital;
      } else if (auto e = access_.reply_error(replies[i], calls[i], true)) {
        throw *e;
      } else {
        std::uint16_t v = ams::get16(replies[i].data.data());
        const TerminalType* t = catalog.find_by_number(v);
        if (!t)
          throw Error(Exit::usage,
                      fmt::format("terminal number {} reports type {} (R8), which the catalog does not know", n, v),
                      "describe it with --catalog DIR, or give --station FILE");
        st.terminals.push_back({t, n, v});
        last = n;
      }
    }
  }
  return last;
}

// The station of a coupler that does not serve table 9, walked by terminal number.
Table9Station AdsReader::walk(const Catalog& catalog, ScanResult& r, const CouplerImage& image,
                              const Table9ScanOptions& opt) {
  Table9Station st;
  st.from_table9 = false;
  r.notes.push_back("the coupler does not serve table 9 (its terminal list); walked by terminal number instead");
  // A number without registers answers an ADS error, and no manual says which: a digital terminal
  // and no terminal at all may answer alike (0x702 or 0x703). So the walk does not end at the first
  // such answer: it asks every number (to kMaxTerminals), and the numbers without registers before
  // the last one with registers are digital terminals. Only the coupler's image lengths showing no
  // digital bit at all make the first such number the end.
  bool no_digital = image.bits && (*image.bits)[2] == 0 && (*image.bits)[3] == 0;
  std::vector<unsigned> none;  // numbers that answered without registers
  unsigned last = walk_numbers(catalog, no_digital, st, none);
  auto unidentified =
      static_cast<unsigned>(std::count_if(none.begin(), none.end(), [&](unsigned n) { return n < last; }));
  bool after = !no_digital && last < adsreg::kMaxTerminals;  // digital terminals after the last: unknown
  if (after && (!image.bits || (*image.bits)[2] || (*image.bits)[3])) {
    if (!opt.check)
      throw Error(Exit::usage,
                  fmt::format("the coupler at {} does not serve table 9 (its terminal list), and after terminal "
                              "number {} it answers no terminal with registers: digital terminals there cannot be "
                              "told from the end of the station, so kscfg cannot lay it out",
                              client_.target().where(), last),
                  "describe the station: --station FILE ('kscfg scan --write FILE' starts one)");
    r.notes.push_back(
        fmt::format("after terminal number {} the coupler answers no terminal with registers: digital "
                    "terminals there (if any) cannot be told from the end of the station{}",
                    last,
                    image.bits ? fmt::format(" (the coupler reports {} output and {} input bit(s) of "
                                             "digital terminals)",
                                             (*image.bits)[2], (*image.bits)[3])
                               : std::string()));
    st.incomplete = true;
  }
  if (unidentified && !opt.check)
    // Their bit counts are unknown, so the image cannot be laid out, and plug positions would
    // not be terminal numbers: a command needs the station described.
    throw Error(Exit::usage,
                fmt::format("the coupler at {} does not serve table 9 (its terminal list) and {} of its terminals "
                            "have no registers, so kscfg cannot lay the station out",
                            client_.target().where(), unidentified),
                "describe the station: --station FILE ('kscfg scan --write FILE' starts one)");
  if (unidentified) {
    r.notes.push_back(
        fmt::format("{} terminal(s) without registers (digital) cannot be identified without table 9 "
                    "and are not listed; plug positions count the terminals with registers",
                    unidentified));
    st.incomplete = true;
  }
  return st;
}

// The coupler: table 9 register 0 names it (9000: BK9000); without it, the device name.
const CouplerProfile& AdsReader::profile(ScanResult& r, const Table9Station& st) {
  unsigned coupler_number = st.coupler_number;
  std::string name = coupler_number ? fmt::format("BK{}", coupler_number) : r.ident.substr(0, r.ident.find(' '));
  const CouplerProfile* prof = nullptr;
  for (const auto& p : coupler_profiles())
    if (p.name == name) prof = &p;
  r.known_coupler = prof != nullptr;
  if (prof) return *prof;
  r.notes.push_back(
      coupler_number
          ? fmt::format("table 9 names coupler {}, which kscfg does not know; laid out with BK9000 settings "
                        "(complete evaluation on, word alignment on, Intel)",
                        coupler_number)
          : "the coupler's name is not one kscfg knows; laid out with BK9000 settings (complete evaluation on, "
            "word alignment on, Intel)");
  return coupler_profile("BK9000");
}

// One batch: R8 and R9 of every terminal with registers (channel 1), and on every channel the
// registers that decide its image format; the ADS watchdog (table 100 register 14) with them.
std::vector<TerminalRegisters> AdsReader::registers(const std::vector<TerminalRead>& reads, ScanResult& r,
                                                    const Table9ScanOptions& opt) {
  struct Want {
    std::size_t terminal;
    unsigned channel, reg;
  };
  std::vector<Want> want;
  std::vector<AdsClient::Call> calls;
  for (std::size_t i = 0; i < reads.size(); ++i) {
    if (!reads[i].registers) continue;
    std::set<unsigned> regs = reads[i].image;
    if (reads[i].check) regs.insert({8, 9});
    for (unsigned ch = 0; ch < reads[i].channels; ++ch)
      for (unsigned reg : regs) {
        if (ch > 0 && (reg == 8 || reg == 9)) continue;
        want.push_back({i, ch, reg});
        calls.push_back(access_.read_call({reads[i].number, ch, reg}));
      }
  }
  if (opt.check) calls.push_back(table_call(adsreg::kTable100, 14, timeout_ms_));
  if (!calls.empty()) step(opt, fmt::format("{} terminal register(s)", calls.size()));
  auto replies = calls.empty() ? std::vector<AdsClient::Reply>{} : client_.transact(calls);
  if (opt.check && !not_served(replies.back().result)) {
    if (auto e = access_.reply_error(replies.back(), calls.back(), true)) throw *e;
    r.watchdog_preset = ams::get16(replies.back().data.data());
  }
  std::vector<TerminalRegisters> got(reads.size());
  for (std::size_t k = 0; k < want.size(); ++k) {
    if (auto e = access_.reply_error(replies[k], calls[k], true)) throw *e;
    std::uint16_t v = ams::get16(replies[k].data.data());
    const Want& w = want[k];
    if (w.reg == 9 && w.channel == 0) {
      got[w.terminal].r9 = v;
      continue;
    }
    auto& per = got[w.terminal].per;
    if (per.size() <= w.channel) per.resize(w.channel + 1);
    per[w.channel][w.reg] = v;
  }
  return got;
}

}  // namespace

std::unique_ptr<Table9Reader> ads_table9_reader(AdsClient& client, unsigned timeout_ms, SilentMemo memo,
                                                const CancelToken* cancel) {
  return std::make_unique<AdsReader>(client, timeout_ms, true, std::move(memo), cancel);
}

AdsScan scan_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms, AdsScanOptions opt) {
  AdsReader reader(client, timeout_ms, opt.check_image, opt.silent_memo, opt.cancel);
  return scan_table9(reader, catalog, opt);
}

}  // namespace kscfg
