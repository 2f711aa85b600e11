// The layout of an ADS coupler's station against the image lengths it reports (discovery/ads_image.hpp).
#include "kscfg/discovery/ads_image.hpp"

#include <arpa/inet.h>
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/link/modbus_client.hpp"

namespace kscfg {

namespace {

// The NetId the URI gives names another device than the host reached (an AMS router): the host's
// Modbus side would not be the coupler's.
bool routed(const AdsTarget& t) {
  if (!t.netid) return false;
  in_addr a{};
  if (inet_pton(AF_INET, t.host.c_str(), &a) != 1) return false;
  const auto* b = reinterpret_cast<const std::uint8_t*>(&a.s_addr);
  const ams::NetId& n = *t.netid;
  return !(n[0] == b[0] && n[1] == b[1] && n[2] == b[2] && n[3] == b[3] && n[4] == 1 && n[5] == 1);
}

std::string onoff(bool b) { return b ? "on" : "off"; }

std::string settings_of(const MappingSettings& s) {
  return fmt::format("complete evaluation {}, word alignment {}, {}", onoff(s.complete_evaluation),
                     onoff(s.word_alignment), s.motorola ? "Motorola" : "Intel");
}

}  // namespace

namespace {

// When the memo says the Modbus TCP side last did not answer (seconds since the epoch), if it does.
std::optional<long long> silent_since(const SilentMemo& memo) {
  if (memo.path.empty()) return std::nullopt;
  RegularFile f = read_regular_file(memo.path, "memo", 64);
  if (!f.exists || !f.refused.empty()) return std::nullopt;
  try {
    std::size_t used = 0;
    long long t = std::stoll(f.text, &used);
    return t;
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

}  // namespace

CouplerImage read_coupler_image(const AdsTarget& target, std::optional<std::uint16_t> r15,
                                std::optional<std::uint16_t> r26, unsigned timeout_ms,
                                const std::function<void(const std::string&)>& trace, const CancelToken* cancel,
                                const SilentMemo& memo) {
  CouplerImage c;
  if (!r15 || !r26) {
    c.unknown = "the coupler does not serve table 100 registers 15 and 26 (its Modbus TCP settings)";
    return c;
  }
  if (*r15 & 1) {
    c.unknown = "the coupler has Modbus TCP disabled (table 100 register 15 bit 0), where it reports its image lengths";
    return c;
  }
  if (routed(target)) {
    c.unknown = "the NetId names a device behind the host reached, whose Modbus TCP side is not the coupler's";
    return c;
  }
  ModbusTarget m;
  m.uri = fmt::format("tcp://{}:{}", target.host, *r26);
  m.host = target.host;
  m.port = *r26 ? *r26 : 502;
  m.unit = 1;
  c.where = fmt::format("Modbus TCP 0x1010..0x1013 at {}", m.where().substr(0, m.where().rfind(" unit")));
  const long long now =
      std::chrono::duration_cast<std::chrono::seconds>(std::chrono::system_clock::now().time_since_epoch()).count();
  if (auto since = silent_since(memo);
      since && !memo.ask_anyway && now >= *since && now - *since < kSilentMemoSeconds) {
    c.silent = true;
    c.unknown = fmt::format(
        "its Modbus TCP side (table 100: port {}), where it reports its image lengths, did not answer {} s ago; "
        "not asked again for {} minutes ('kscfg scan' or --rescan asks)",
        *r26, now - *since, kSilentMemoSeconds / 60);
    return c;
  }
  ModbusOptions mo;
  mo.connect_timeout_ms = std::clamp(timeout_ms, 100u, 1000u);
  mo.response_timeout_ms = std::clamp(timeout_ms, 100u, 1000u);
  mo.retries = 0;
  mo.timeout_retries = 0;
  mo.trace = trace;
  mo.cancel = cancel;
  const auto began = std::chrono::steady_clock::now();
  auto keep_memo = [&](bool silent) noexcept {
    if (memo.path.empty()) return;
    try {
      if (silent) {
        std::filesystem::create_directories(std::filesystem::path(memo.path).parent_path());
        write_file_atomic(memo.path, std::to_string(now) + "\n", true);
      } else {
        std::error_code ec;
        std::filesystem::remove(memo.path, ec);
      }
    } catch (...) {
      // A memo that cannot be kept costs the next command the wait, nothing more.
    }
  };
  try {
    ModbusClient client(m, mo);
    auto v = client.read_optional(mbmap::kImageLengths, 4);
    keep_memo(false);
    if (!v || v->size() != 4) {
      c.unknown = fmt::format("its Modbus TCP side ({}) refuses the image lengths 0x1010..0x1013", m.where());
      return c;
    }
    c.bits = std::array<unsigned, 4>{(*v)[0], (*v)[1], (*v)[2], (*v)[3]};
    if (trace)
      trace(fmt::format("ads: image lengths from {}: complex {}/{} bits out/in, digital {}/{}", c.where, (*v)[0],
                        (*v)[1], (*v)[2], (*v)[3]));
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) throw;
    // No answer within the bound (not a refusal, which costs nothing): kept for the next commands.
    c.silent = std::chrono::steady_clock::now() - began >= std::chrono::milliseconds(mo.connect_timeout_ms * 9 / 10);
    keep_memo(c.silent);
    c.unknown = fmt::format(
        "its Modbus TCP side (table 100: port {}), where it reports its image lengths, does not "
        "answer: {}",
        *r26, e.what());
  }
  return c;
}

void judge_image(StationLayout& L, const CouplerImage& c, const StationSpec& spec, const Catalog& catalog,
                 const RegisterSource& regs, const std::string& origin) {
  L.image_refused.clear();
  L.image_refused_hint.clear();
  L.image_unconfirmed.clear();
  if (!c.bits) {
    L.image_unconfirmed = fmt::format(
        "the coupler's image lengths are unknown ({}): the layout of {} is the "
        "family's settings ({}), not confirmed by the coupler",
        c.unknown, origin, settings_of(L.settings));
    return;
  }
  const auto& b = *c.bits;
  auto fits = [&](const StationLayout& X) {
    return X.complex_out * 8 == b[0] && X.complex_in * 8 == b[1] && X.digital_out_bits == b[2] &&
           X.digital_in_bits == b[3];
  };
  if (fits(L)) return;
  std::string said = fmt::format(
      "the coupler reports {} output and {} input byte(s) of complex terminals, {} and {} "
      "bit(s) of digital ones ({})",
      b[0] / 8, b[1] / 8, b[2], b[3], c.where);
  std::string laid = fmt::format(
      "{} laid out with complete evaluation {} and word alignment {} takes {} and {}, {} "
      "and {}",
      origin, onoff(L.settings.complete_evaluation), onoff(L.settings.word_alignment), L.complex_out, L.complex_in,
      L.digital_out_bits, L.digital_in_bits);
  // Which settings lay these terminals out to the coupler's lengths (Motorola moves no byte).
  std::vector<MappingSettings> match;
  for (bool ce : {true, false})
    for (bool wa : {true, false}) {
      MappingSettings s = L.settings;
      s.complete_evaluation = ce;
      s.word_alignment = wa;
      if (ce == L.settings.complete_evaluation && wa == L.settings.word_alignment) continue;
      if (fits(compute_layout(spec, catalog, s, regs))) match.push_back(s);
    }
  if (match.size() == 1) {
    const MappingSettings& s = match.front();
    std::vector<std::string> set, keys, flags;
    if (s.complete_evaluation != L.settings.complete_evaluation) {
      set.push_back("complete evaluation " + onoff(s.complete_evaluation));
      keys.push_back(fmt::format("complete-evaluation = {}", s.complete_evaluation));
      flags.push_back("--complete-evaluation " + onoff(s.complete_evaluation));
    }
    if (s.word_alignment != L.settings.word_alignment) {
      set.push_back("word alignment " + onoff(s.word_alignment));
      keys.push_back(fmt::format("word-alignment = {}", s.word_alignment));
      flags.push_back("--word-alignment " + onoff(s.word_alignment));
    }
    auto join = [](const std::vector<std::string>& v, const char* sep) {
      return v.size() == 2 ? v[0] + sep + v[1] : v[0];
    };
    std::string what = join(set, " and ");
    L.image_refused = fmt::format("the coupler is set to {}: {}; {} (with {}, the coupler's)", what, said, laid, what);
    L.image_refused_hint = fmt::format(
        "give the coupler's settings: --station FILE with [mapping] {} ('kscfg scan "
        "{} --write FILE' writes one); nothing was read from the image",
        join(keys, ", "), join(flags, " "));
    return;
  }
  L.image_refused = fmt::format("{}; {}{}", said, laid,
                                match.empty() ? ", and no setting of complete evaluation and word alignment lays "
                                                "these terminals out so: the station is not the one described (a "
                                                "terminal added or removed since the coupler started, or a mapping "
                                                "register such as R34/R35 changed, which takes effect at its next "
                                                "start)"
                                              : ", as several settings would: which one the coupler has is unknown");
  L.image_refused_hint =
      "nothing was read from the image; power the coupler off and on, then 'kscfg scan' shows "
      "what it has";
}

}  // namespace kscfg
