// kscfg decode control|status VALUE: explain a process-data control/status byte or word.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/parameters.hpp"

namespace kscfg::cli {

namespace {

class Decode : public Command {
 public:
  std::string name() const override { return "decode"; }
  std::string brief() const override { return "Explain a control or status byte/word seen in a PLC"; }
  std::string man() const override {
    return "Decodes a process-data control byte (\\fBcontrol\\fR, outputs) or status byte (\\fBstatus\\fR, "
           "inputs) of a terminal type, bit by bit, from the catalog's tables: KL6001 CT/ST (TR, RA, IR, OL "
           "and TA, RR, IA, BUF_F, IL), KL6031/KL6041 control and status words (\\fB\\-\\-image large\\fR for "
           "the 16-bit word with OL/IL in the high byte) and bytes, the CX serial interface's word in KL6xx1 mode "
           "(\\fB\\-T CX\\-KL6xx1\\fR), KL5101 control and status. For a terminal with registers a value with "
           "bit 7 set is decoded as a register request or acknowledge. The type comes from \\fB\\-T\\fR, or "
           "from the selected terminal of the station.";
  }
  std::vector<std::string> examples() const override {
    return {"decode status 0x35 -T KL6001", "decode control 0x0321 -T KL6031 --image large",
            "decode status 0x9F -T KL6001", "decode status 0x4002 -T CX-KL6xx1"};
  }
  std::vector<std::string> completions() const override { return {"control", "status"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("KIND", kind_, "control or status")->required()->option_text("KIND");
    sub.add_option("VALUE", value_, "The byte or word, e.g. 0x35")->required()->option_text("VALUE");
    sub.add_option("-T,--type", type_, "Terminal type (default: the selected terminal's)")->option_text("TYPE");
    sub.add_option("--image", image_, "Image format (e.g. large; default: the type's default format)")
        ->option_text("FORMAT");
  }
  int run(Context& ctx) override {
    if (kind_ != "control" && kind_ != "status")
      throw Error(Exit::usage, fmt::format("unknown kind '{}': use control or status", kind_));
    std::uint16_t v = parse_value(value_);
    const TerminalType* type = nullptr;
    std::string image = image_;
    if (!type_.empty()) {
      type = &ctx.catalog().get(type_);
      if (image.empty()) {
        const ImageFormat* f = type->image_for(type->defaults());
        if (f) image = f->name;
      }
    } else {
      const TerminalImage& t = ctx.resolver().layout().terminal(ctx.terminal_position());
      type = t.type;
      if (image.empty()) image = t.format;
    }
    Decoded d = decode_ctst(*type, kind_, image, v);
    if (ctx.json()) {
      nlohmann::json bits = nlohmann::json::object();
      for (const auto& b : d.bits) bits[b.name] = b.value;
      nlohmann::json j{
          {"type", type->type}, {"kind", kind_}, {"value", v}, {"width", d.width}, {"register_mode", d.register_mode},
          {"bits", bits}};
      if (d.register_mode) {
        j["register"] = d.reg;
        j["write"] = d.write;
      }
      print_json(j);
      return 0;
    }
    std::string bin;
    for (int i = static_cast<int>(d.width) - 1; i >= 0; --i) bin += ((v >> i) & 1) ? '1' : '0';
    std::cout << fmt::format("{} {} 0x{:0{}X} = 0b{}\n", type->type, kind_, v, d.width / 4, bin);
    if (d.register_mode) {
      if (kind_ == "control") std::cout << fmt::format("  register mode: {} R{}\n", d.write ? "write" : "read", d.reg);
      else
        std::cout << fmt::format("  register mode: acknowledge of R{}{}\n", d.reg,
                                 d.write ? " (bit 6 set: the text's form of a write ack)" : "");
      return 0;
    }
    std::cout << (type->has_registers ? "  process data mode (REG = 0)\n"
                                      : "  process data (the type has no register set)\n");
    for (const auto& b : d.bits)
      std::cout << fmt::format("  {:<12} {:<3} {}{}\n", b.name, b.value, b.desc,
                               b.meaning.empty() ? "" : (b.desc.empty() ? "" : ": ") + b.meaning);
    return 0;
  }

 private:
  std::string kind_, value_, type_, image_;
};

}  // namespace

std::unique_ptr<Command> make_decode() { return std::make_unique<Decode>(); }

}  // namespace kscfg::cli
