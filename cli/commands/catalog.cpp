// kscfg catalog [TYPE]: the terminal types kscfg knows, or one type's registers and parameters.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../help.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/describe.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg::cli {

namespace {

std::string elements_text(const std::vector<Element>& v) {
  std::string s;
  for (const auto& e : v) {
    std::string t;
    switch (e.kind) {
      case Element::Kind::ctst: t = "CT/ST"; break;
      case Element::Kind::ctst_word: t = "CT/ST+" + e.hi; break;
      case Element::Kind::word: t = e.lo + "+" + e.hi; break;
      case Element::Kind::dword: t = e.names[0] + "+" + e.names[1] + "+" + e.names[2] + "+" + e.names[3]; break;
      case Element::Kind::byte: t = e.lo; break;
      case Element::Kind::pad: t = "(" + e.lo + ")"; break;
      case Element::Kind::bytes:
        t = e.count_register ? fmt::format("{}0..{}[R{}]", e.lo, e.lo, *e.count_register)
                             : fmt::format("{}0..{}{}", e.lo, e.lo, e.count ? e.count - 1 : 0);
        break;
    }
    s += (s.empty() ? "" : " ") + t;
  }
  return s;
}

unsigned described_count(const TerminalType& t) {
  unsigned n = 0;
  for (const auto& r : t.regs) n += r.described && !r.reserved;
  return n;
}

// Why a type with a register set has no named parameters: its `coverage` line, or that none is
// recorded.
std::string coverage_of(const TerminalType& t) {
  if (!t.coverage.empty()) return t.coverage;
  return described_count(t) ? "registers described, no named parameters (no reason recorded)"
                            : "no register description in the catalog (no reason recorded)";
}

class CatalogCmd : public Command {
 public:
  std::string name() const override { return "catalog"; }
  std::string brief() const override { return "List known terminal types, or describe one"; }
  std::string man() const override {
    return "Without \\fITYPE\\fR, lists every terminal type kscfg knows (built in, plus \\fB\\-\\-catalog\\fR / "
           "\\fBKSCFG_CATALOG\\fR) with its family, R8 number, how many named parameters it has and its title, "
           "then the coverage: how many of the types with a register set have named parameters and their "
           "registers described, and every one without named parameters with the reason the catalog gives "
           "(its \\fBcoverage\\fR line: e.g. no public register description found, and the pages searched). "
           "With \\fITYPE\\fR, shows the type's described registers with defaults and storage, its named "
           "parameters with their values, its process-image formats, the family it includes and where the "
           "facts come from. The description format is in \\fBkscfg\\-catalog\\fR(5).";
  }
  std::vector<std::string> examples() const override {
    return {"catalog", "catalog KL6001", "--catalog ./types catalog"};
  }
  void add_cli(CLI::App& sub) override { sub.add_option("TYPE", type_, "Terminal type")->option_text("TYPE"); }
  int run(Context& ctx) override {
    const Catalog& cat = ctx.catalog();
    if (type_.empty()) return list(ctx, cat);
    const TerminalType& t = cat.get(type_);
    if (ctx.json()) {
      nlohmann::json regs = nlohmann::json::array(), params = nlohmann::json::array(), images = nlohmann::json::array();
      for (const auto& r : t.regs)
        if (r.described || r.addr == 8 || r.addr == 9)
          regs.push_back({{"register", r.addr},
                          {"name", r.name},
                          {"default", r.def},
                          {"storage", proto::storage_name(r.storage)},
                          {"writable", r.writable},
                          {"description", r.desc}});
      for (const auto& p : t.params) {
        nlohmann::json values = nlohmann::json::array();
        for (const auto& c : param_choices(p)) values.push_back(param_json(c));
        params.push_back({{"name", p.name},
                          {"register", p.reg},
                          {"mask", p.mask},
                          {"choices", values},
                          {"default", param_json(decode_param(p, t.regs[p.reg].def))},
                          {"measured_in", p.unit.empty() ? nlohmann::json(nullptr) : nlohmann::json(p.unit)},
                          {"description", p.desc}});
      }
      for (const auto& im : t.images) images.push_back({{"name", im.name}, {"elements", elements_text(im.out)}});
      print_json({{"type", t.type},
                  {"title", t.title},
                  {"family", t.family},
                  {"r8", t.has_registers ? nlohmann::json(t.r8) : nlohmann::json(nullptr)},
                  {"channels", t.channels},
                  {"registers", regs},
                  {"params", params},
                  {"images", images},
                  {"source", t.source},
                  {"origin", t.origin},
                  {"bases", t.bases},
                  {"coverage", t.coverage.empty() ? nlohmann::json(nullptr) : nlohmann::json(t.coverage)},
                  {"unverified", t.unverified.empty() ? nlohmann::json(nullptr) : nlohmann::json(t.unverified)},
                  {"factory_reset", t.reset == FactoryReset::r7 ? "r7" : "defaults"}});
      return 0;
    }
    std::cout << fmt::format("{}  {}\nfamily {}, {} channel(s), factory reset by {}\nsource: {}\n", t.type, t.title,
                             t.family, t.channels, t.reset == FactoryReset::r7 ? "R7 = 0x7000" : "catalog defaults",
                             t.source.empty() ? t.origin : t.source);
    if (!t.bases.empty()) std::cout << fmt::format("family description: {}\n", fmt::join(t.bases, ", "));
    if (!t.unverified.empty()) std::cout << fmt::format("unverified: {}\n", t.unverified);
    if (t.has_registers && t.params.empty()) std::cout << fmt::format("coverage: {}\n", coverage_of(t));
    if (t.has_registers) {
      std::cout << "\nregisters:\n";
      for (const auto& r : t.regs)
        if (r.described || r.addr == 8 || r.addr == 9)
          std::cout << fmt::format("  R{:<3} {:<20} {:<7} {}{} {}\n", r.addr, register_label(t, r.addr),
                                   proto::storage_name(r.storage), r.typical ? "~" : "", hex4(r.def),
                                   r.reserved ? "reserved" : r.desc);
    }
    if (!t.params.empty()) {
      std::cout << "\nparameters:\n";
      for (const auto& p : t.params) {
        std::string vals;
        for (const auto& c : param_choices(p)) vals += (vals.empty() ? "" : " ") + c;
        std::string needs;
        for (const auto& r : p.requirements) needs += fmt::format(" (with {} {})", r.param, r.value);
        std::cout << fmt::format("  {:<20} R{:<2} {} default {}: {}{}\n", p.name, p.reg, vals,
                                 decode_param(p, t.regs[p.reg].def, p.reg_hi ? t.regs[*p.reg_hi].def : 0),
                                 param_description(p.desc), needs);
      }
    }
    if (!t.images.empty()) {
      std::cout << "\nprocess image:\n";
      for (const auto& im : t.images) {
        if (im.complex()) std::cout << fmt::format("  {:<12} {}\n", im.name, elements_text(im.out));
        else std::cout << fmt::format("  {:<12} {} bit(s) in, {} bit(s) out\n", im.name, im.bits_in, im.bits_out);
      }
    }
    return 0;
  }

 private:
  // Every type, then the coverage: the types with a register set, which have named parameters and
  // which not (with the catalog's reason).
  int list(Context& ctx, const Catalog& cat) {
    nlohmann::json arr = nlohmann::json::array();
    unsigned reg_types = 0, with_params = 0, described = 0;
    std::vector<const TerminalType*> without;
    if (!ctx.json())
      std::cout << fmt::format("{:<10} {:<12} {:<5} {:<6} {}\n", "TYPE", "FAMILY", "R8", "PARAMS", "TITLE");
    for (const auto& [n, t] : cat.types()) {
      unsigned nd = described_count(*t);
      if (t->has_registers) {
        ++reg_types;
        with_params += !t->params.empty();
        described += nd > 0;
        if (t->params.empty()) without.push_back(t.get());
      }
      if (ctx.json())
        arr.push_back(
            {{"type", n},
             {"family", t->family},
             {"r8", t->has_registers ? nlohmann::json(t->r8) : nlohmann::json(nullptr)},
             {"title", t->title},
             {"origin", t->origin},
             {"param_count", t->params.size()},
             {"described_count", nd},
             {"coverage",
              t->has_registers && t->params.empty() ? nlohmann::json(coverage_of(*t)) : nlohmann::json(nullptr)},
             {"unverified", t->unverified.empty() ? nlohmann::json(nullptr) : nlohmann::json(t->unverified)}});
      else
        std::cout << fmt::format("{:<10} {:<12} {:<5} {:<6} {}{}\n", n, t->family,
                                 t->has_registers ? std::to_string(t->r8) : "-",
                                 t->has_registers ? std::to_string(t->params.size()) : "-", t->title,
                                 t->unverified.empty() ? "" : " (unverified)");
    }
    if (ctx.json()) {
      print_json({{"types", arr},
                  {"summary",
                   {{"type_count", cat.types().size()},
                    {"register_types", reg_types},
                    {"with_params", with_params},
                    {"described", described}}}});
      return 0;
    }
    std::cout << fmt::format(
        "\n{} types; {} have a register set: {} with named parameters, {} with registers described.\n",
        cat.types().size(), reg_types, with_params, described);
    if (!without.empty()) {
      std::cout << fmt::format("Without named parameters ({}):\n", without.size());
      for (const auto* t : without) std::cout << fmt::format("  {:<10} {}\n", t->type, coverage_of(*t));
    }
    return 0;
  }

  std::string type_;
};

}  // namespace

std::unique_ptr<Command> make_catalog() { return std::make_unique<CatalogCmd>(); }

}  // namespace kscfg::cli
