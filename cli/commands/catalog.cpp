// kscfg catalog [TYPE]: the terminal types kscfg knows, or one type's registers and parameters.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../help.hpp"
#include "kscfg/base/parse.hpp"
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

class CatalogCmd : public Command {
 public:
  std::string name() const override { return "catalog"; }
  std::string brief() const override { return "List known terminal types, or describe one"; }
  std::string man() const override {
    return "Without \\fITYPE\\fR, lists every terminal type kscfg knows (built in, plus \\fB\\-\\-catalog\\fR / "
           "\\fBKSCFG_CATALOG\\fR) with its family, R8 number and title. With \\fITYPE\\fR, shows the type's "
           "described registers with defaults and storage, its named parameters with their values, its "
           "process-image formats and where the facts come from. The description format is in "
           "\\fBkscfg\\-catalog\\fR(5).";
  }
  std::vector<std::string> examples() const override {
    return {"catalog", "catalog KL6001", "--catalog ./types catalog"};
  }
  void add_cli(CLI::App& sub) override { sub.add_option("TYPE", type_, "Terminal type")->option_text("TYPE"); }
  int run(Context& ctx) override {
    const Catalog& cat = ctx.catalog();
    if (type_.empty()) {
      nlohmann::json arr = nlohmann::json::array();
      for (const auto& [n, t] : cat.types()) {
        if (ctx.json())
          arr.push_back({{"type", n},
                         {"family", t->family},
                         {"r8", t->has_registers ? nlohmann::json(t->r8) : nlohmann::json(nullptr)},
                         {"title", t->title},
                         {"origin", t->origin}});
        else
          std::cout << fmt::format("{:<8} {:<12} {:<5} {}\n", n, t->family,
                                   t->has_registers ? std::to_string(t->r8) : "-", t->title);
      }
      if (ctx.json()) print_json({{"types", arr}});
      return 0;
    }
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
                  {"factory_reset", t.reset == FactoryReset::r7 ? "r7" : "defaults"}});
      return 0;
    }
    std::cout << fmt::format("{}  {}\nfamily {}, {} channel(s), factory reset by {}\nsource: {}\n", t.type, t.title,
                             t.family, t.channels, t.reset == FactoryReset::r7 ? "R7 = 0x7000" : "catalog defaults",
                             t.source.empty() ? t.origin : t.source);
    if (t.has_registers) {
      std::cout << "\nregisters:\n";
      for (const auto& r : t.regs)
        if (r.described || r.addr == 8 || r.addr == 9)
          std::cout << fmt::format("  R{:<3} {:<16} {:<7} {} {}\n", r.addr, r.name.empty() ? "-" : r.name,
                                   proto::storage_name(r.storage), hex4(r.def), r.desc);
    }
    if (!t.params.empty()) {
      std::cout << "\nparameters:\n";
      for (const auto& p : t.params) {
        std::string vals;
        for (const auto& c : param_choices(p)) vals += (vals.empty() ? "" : " ") + c;
        std::cout << fmt::format("  {:<20} R{:<2} {} default {}: {}\n", p.name, p.reg, vals,
                                 decode_param(p, t.regs[p.reg].def), param_description(p.desc));
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
  std::string type_;
};

}  // namespace

std::unique_ptr<Command> make_catalog() { return std::make_unique<CatalogCmd>(); }

}  // namespace kscfg::cli
