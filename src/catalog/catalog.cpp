// Catalog queries: the built-in and user catalogs, lookup by name and R8, and the questions asked
// of a parsed TerminalType. Parsing the TOML descriptions is in catalog_parse.cpp.
#include "kscfg/catalog/catalog.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <stdexcept>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/base/suggest.hpp"

namespace kscfg {

std::uint16_t Scale::word(double v) const {
  double r = raw0 + (v - value0) * (raw1 - raw0) / (value1 - value0);
  double lo = is_unsigned() ? 0 : -32768, hi = is_unsigned() ? 65535 : 32767;
  r = std::clamp(std::round(r), lo, hi);
  return static_cast<std::uint16_t>(static_cast<std::int32_t>(r) & 0xFFFF);
}

unsigned ParamDef::shift() const {
  unsigned s = 0;
  while (s < 16 && !((mask >> s) & 1u)) ++s;
  return s;
}

unsigned ParamDef::width() const {
  unsigned w = 0;
  for (unsigned m = mask; m; m >>= 1) w += m & 1u;
  return reg_hi ? w + 16 : w;
}

std::string TerminalType::source_url(const std::string& s) const {
  if (auto it = sources.find(s); it != sources.end()) return it->second;
  return s;
}

const ParamDef* TerminalType::param(std::string_view name) const {
  for (const auto& p : params)
    if (p.name == name) return &p;
  return nullptr;
}

std::vector<std::string> TerminalType::param_names() const {
  std::vector<std::string> out;
  for (const auto& p : params) out.push_back(p.name);
  return out;
}

const ImageFormat* TerminalType::image_for(const std::array<std::uint16_t, proto::kRegisterCount>& r) const {
  for (const auto& img : images)
    if (!img.when || (r[img.when->reg] & img.when->mask) == img.when->value) return &img;
  return nullptr;
}

std::array<std::uint16_t, proto::kRegisterCount> TerminalType::defaults() const {
  std::array<std::uint16_t, proto::kRegisterCount> d{};
  for (unsigned i = 0; i < proto::kRegisterCount; ++i) d[i] = regs[i].def;
  return d;
}

Catalog Catalog::builtin() {
  Catalog c;
  for (const auto& f : builtin_catalog_files()) {
    std::string_view stem = f.name;
    if (auto slash = stem.find_last_of('/'); slash != std::string_view::npos) stem.remove_prefix(slash + 1);
    stem = stem.substr(0, stem.rfind(".toml"));
    c.pending_[std::string(stem)] = &f;
  }
  return c;
}

const TerminalType* Catalog::parse_pending(std::map<std::string, const EmbeddedFile*>::iterator it) const {
  // Called with the mutex held. The entry goes from pending_ to types_ (or throws, and stays).
  std::string origin = std::string("built-in:") + it->second->name;
  auto t = parse_description(origin, it->second->text, base_finder());
  if (t->type != it->first)
    throw Error(Exit::file, fmt::format("{}: describes type '{}', but a built-in file is named after its type ({})",
                                        origin, t->type, it->first));
  pending_.erase(it);
  auto& slot = types_[t->type];
  slot = std::move(t);
  return slot.get();
}

const std::map<std::string, std::shared_ptr<const TerminalType>>& Catalog::types() const {
  std::lock_guard<std::mutex> lock(*mu_);
  while (!pending_.empty()) parse_pending(pending_.begin());
  return types_;
}

static std::filesystem::path g_user_dir;
static bool g_standard_built = false;

void set_user_catalog_dir(const std::filesystem::path& dir) {
  if (g_standard_built) throw std::logic_error("set_user_catalog_dir after the catalog was built");
  g_user_dir = dir;
}

const Catalog& Catalog::standard() {
  static const Catalog cat = [] {
    g_standard_built = true;
    Catalog c = builtin();
    std::filesystem::path dir = g_user_dir;
    if (dir.empty())
      if (const char* env = std::getenv("KSCFG_CATALOG"); env && *env) dir = env;
    // Said as what it is: a file given as the directory is not a directory that "does not exist".
    if (std::string what = dir.empty() ? "" : not_a_directory(dir.string()); !what.empty())
      throw Error(Exit::file, fmt::format("catalog directory '{}' {}", dir.string(), what),
                  "--catalog and KSCFG_CATALOG name a directory of TYPE.toml files");
    if (!dir.empty()) c.add_dir(dir);
    return c;
  }();
  return cat;
}

const TerminalType* Catalog::find(std::string_view type) const {
  std::string up(type);
  for (auto& ch : up) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  std::lock_guard<std::mutex> lock(*mu_);
  for (const std::string& k : {up, std::string(type)}) {
    if (auto it = types_.find(k); it != types_.end()) return it->second.get();
    if (auto it = pending_.find(k); it != pending_.end()) return parse_pending(it);
  }
  // Names with lower-case letters (CX-KL6xx1) match in any case too.
  auto same = [&](const std::string& k) {
    if (k.size() != up.size()) return false;
    for (std::size_t i = 0; i < k.size(); ++i)
      if (std::toupper(static_cast<unsigned char>(k[i])) != static_cast<unsigned char>(up[i])) return false;
    return true;
  };
  for (const auto& [k, t] : types_)
    if (same(k)) return t.get();
  for (auto it = pending_.begin(); it != pending_.end(); ++it)
    if (same(it->first)) return parse_pending(it);
  return nullptr;
}

const TerminalType& Catalog::get(std::string_view type) const {
  if (const auto* t = find(type)) return *t;
  auto hint = did_you_mean_type(type, names());
  throw Error(Exit::usage,
              fmt::format("unknown terminal type {}{}", quote_input(type), hint.empty() ? "" : "; " + hint),
              "kscfg catalog lists the known types");
}

const TerminalType* Catalog::find_by_number(std::uint16_t number) const {
  for (const auto& [k, t] : types())
    if (t->has_registers && t->r8 == number) return t.get();
  return nullptr;
}

std::vector<std::string> Catalog::names() const {
  std::lock_guard<std::mutex> lock(*mu_);
  std::vector<std::string> out;
  for (const auto& [k, t] : types_) out.push_back(k);
  for (const auto& [k, f] : pending_) out.push_back(k);
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace kscfg
