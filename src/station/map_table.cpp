// The map as text: the station table and the per-terminal annex view (kscfg map, map -t POS).
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/station/map.hpp"
#include "map_detail.hpp"

namespace kscfg {

using namespace map_detail;

namespace {

std::string byte_names(const std::vector<ImageByte>& bytes) {
  std::string s;
  for (const auto& b : bytes) {
    if (!s.empty()) s += ' ';
    s += b.name;
  }
  return s;
}

void table_section(std::string& out, const StationLayout& L, const CouplerProfile& p, bool input) {
  auto entries = map_entries(L, input);
  std::size_t bytes = input ? L.in_bytes : L.out_bytes;
  std::size_t complex = input ? L.complex_in : L.complex_out;
  std::size_t bits = input ? L.digital_in_bits : L.digital_out_bits;
  std::size_t limit = image_limit(p, input);
  out += fmt::format("\n{}: {} bytes (complex {}, digital {} bits{})\n", input ? "Inputs" : "Outputs", bytes, complex,
                     bits, limit ? fmt::format("; the {} takes up to {}", p.name, limit) : "");
  if (entries.empty()) {
    out += "  (none)\n";
    return;
  }
  struct Row {
    std::string offset, size, pos, type, ch, reg, content;
  };
  std::vector<Row> rows;
  rows.push_back({"offset", "size", "pos", "type", "ch",
                  p.modbus ? "register"
                  : p.ads  ? "ADS group:offset"
                           : "",
                  "content"});
  auto ads = [&](std::size_t offset) {
    return fmt::format("0x{:04X}:{}", input ? kAdsInputGroup : kAdsOutputGroup, offset);
  };
  for (const auto& e : entries) {
    Row r;
    if (e.digital) {
      r.offset = fmt::format("{}.{}", e.offset, e.bit);
      r.size = fmt::format("{} bit", e.size);
      r.ch = "-";
      std::size_t last = e.offset * 8 + e.bit + e.size - 1;
      r.reg = p.modbus ? register_range(input, e.offset, last / 8) : p.ads ? ads(e.offset) : "";
      r.content = "bits " + bit_range(e);
      if (p.modbus) r.content += " (" + bit_numbers(e) + ")";
    } else {
      r.offset = fmt::format("{}", e.offset);
      r.size = fmt::format("{}", e.size);
      r.ch = fmt::format("{}", e.channel);
      r.reg = p.modbus ? register_range(input, e.offset, e.offset + e.size - 1) : p.ads ? ads(e.offset) : "";
      r.content = byte_names(e.bytes);
    }
    r.pos = fmt::format("{}", e.position);
    r.type = e.type;
    rows.push_back(std::move(r));
  }
  std::size_t w[6] = {0, 0, 0, 0, 0, 0};
  for (const auto& r : rows) {
    w[0] = std::max(w[0], r.offset.size());
    w[1] = std::max(w[1], r.size.size());
    w[2] = std::max(w[2], r.pos.size());
    w[3] = std::max(w[3], r.type.size());
    w[4] = std::max(w[4], r.ch.size());
    w[5] = std::max(w[5], r.reg.size());
  }
  for (const auto& r : rows) {
    std::string line = fmt::format("  {:<{}}  {:>{}}  {:>{}}  {:<{}}  {:>{}}  ", r.offset, w[0], r.size, w[1], r.pos,
                                   w[2], r.type, w[3], r.ch, w[4]);
    if (p.modbus || p.ads) line += fmt::format("{:<{}}  ", r.reg, w[5]);
    line += r.content;
    while (!line.empty() && line.back() == ' ') line.pop_back();
    out += line + '\n';
  }
}

std::string terminal_header(const TerminalImage& t) {
  if (t.inferred) return fmt::format("Terminal {}: {} ({})", t.position, digital_label(t), fits_text(t));
  return fmt::format("Terminal {}: {} ({})", t.position, t.type->type, t.type->title);
}

}  // namespace

std::string render_table(const StationLayout& L, const CouplerProfile& p) {
  std::string out = fmt::format("{} ({}): {}\n", p.name,
                                p.ads      ? "ADS: image on port 300, registers on port 100"
                                : p.modbus ? p.family + ", Modbus"
                                           : p.family,
                                settings_text(L));
  table_section(out, L, p, true);
  table_section(out, L, p, false);
  std::vector<std::string> none;
  for (const auto& t : L.terminals)
    if (!t.complex && !t.bits_in && !t.bits_out) none.push_back(fmt::format("{} {}", t.position, shown_type(t)));
  if (!none.empty()) {
    out += "\nNo process image:";
    for (std::size_t i = 0; i < none.size(); ++i) out += (i ? ", " : " ") + none[i];
    out += '\n';
  }
  if (p.modbus)
    out += fmt::format(
        "\nModbus: input register n = input bytes 2n (low) and 2n+1 (high) at 0x{:04X}+n; outputs at "
        "0x{:04X}+n; discrete inputs and coils count from the first digital bit.\n",
        kModbusInputBase, kModbusOutputBase);
  if (p.ads)
    out += fmt::format(
        "\nADS: port {}, index group 0x{:04X} (inputs) or 0x{:04X} (outputs), index offset = the byte "
        "offset (0..511), length in bytes; a digital terminal's bits are read with their bytes.\n",
        kAdsImagePort, kAdsInputGroup, kAdsOutputGroup);
  return out;
}

std::vector<AnnexRow> annex_rows(const std::vector<ImageByte>& bytes, std::size_t base) {
  std::vector<AnnexRow> rows;
  if (bytes.empty()) return rows;
  std::size_t lo = (bytes.front().offset - base) / 2, hi = (bytes.back().offset - base) / 2;
  for (std::size_t w = hi + 1; w-- > lo;) {
    AnnexRow r;
    r.offset = w;
    for (const auto& b : bytes) {
      if ((b.offset - base) / 2 != w) continue;
      std::string name = b.index < 0 ? "" : b.name;
      if ((b.offset - base) % 2) r.high = name;
      else r.low = name;
    }
    rows.push_back(std::move(r));
  }
  return rows;
}

namespace {

void annex_table(std::string& out, const std::vector<ImageByte>& bytes, std::size_t base, bool input, bool both,
                 const CouplerProfile& p) {
  auto rows = annex_rows(bytes, base);
  std::size_t wh = std::string("high byte").size(), wl = std::string("low byte").size();
  for (const auto& r : rows) {
    wh = std::max(wh, r.high.size());
    wl = std::max(wl, r.low.size());
  }
  std::string head =
      fmt::format("    {:<10}  {:<{}}  {:<{}}  {}", "I/O offset", "high byte", wh, "low byte", wl, "image bytes");
  if (p.modbus) head += both ? "   registers (in / out)" : "   register";
  out += head + '\n';
  for (const auto& r : rows) {
    std::size_t b0 = base + 2 * r.offset;
    std::string line =
        fmt::format("    {:<10}  {:<{}}  {:<{}}  {:<11}", r.offset, r.high, wh, r.low, wl, byte_range(b0, b0 + 1));
    if (p.modbus) {
      line += "   ";
      if (both) line += register_range(true, b0, b0 + 1) + " / " + register_range(false, b0, b0 + 1);
      else line += register_range(input, b0, b0 + 1);
    }
    while (!line.empty() && line.back() == ' ') line.pop_back();
    out += line + '\n';
  }
}

bool same_shape(const std::vector<ImageByte>& a, std::size_t abase, const std::vector<ImageByte>& b,
                std::size_t bbase) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (a[i].name != b[i].name || a[i].offset - abase != b[i].offset - bbase) return false;
  return true;
}

}  // namespace

std::string render_terminal(const StationLayout& L, const CouplerProfile& p, unsigned position) {
  const TerminalImage& t = L.terminal(position);
  std::string out = terminal_header(t) + '\n';
  out += fmt::format("  on {}: {}\n", p.name, settings_text(L));
  if (!t.complex) {
    if (!t.bits_in && !t.bits_out) {
      out += "  no process image\n";
      return out;
    }
    for (bool input : {true, false}) {
      for (const auto& e : map_entries(L, input)) {
        if (e.position != position) continue;
        out += fmt::format("  {}: {} bit{} at {}", input ? "inputs" : "outputs", e.size, e.size == 1 ? "" : "s",
                           bit_range(e));
        if (p.modbus)
          out += fmt::format(" (register {}, {})",
                             register_range(input, e.offset, (e.offset * 8 + e.bit + e.size - 1) / 8), bit_numbers(e));
        if (p.ads)
          out += fmt::format(" (ADS port {}, index group 0x{:04X}, offset {})", kAdsImagePort,
                             input ? kAdsInputGroup : kAdsOutputGroup, e.offset);
        out += '\n';
      }
    }
    return out;
  }
  out += fmt::format("  format {}; inputs {} bytes at {}, outputs {} bytes at {}\n", t.format, t.in_size, t.in_offset,
                     t.out_size, t.out_offset);
  if (p.ads)
    out +=
        fmt::format("  ADS port {}: index group 0x{:04X} offset {} ({} bytes), 0x{:04X} offset {} ({} bytes)\n",
                    kAdsImagePort, kAdsInputGroup, t.in_offset, t.in_size, kAdsOutputGroup, t.out_offset, t.out_size);
  out += "  (I/O offset in words from the terminal's first byte, as in the manuals' annex tables)\n";
  for (std::size_t c = 0; c < t.channels.size(); ++c) {
    const auto& ch = t.channels[c];
    std::string chn = t.channels.size() > 1 ? fmt::format("channel {} ", c + 1) : "";
    if (!ch.in.empty() && !ch.out.empty() && same_shape(ch.in, t.in_offset, ch.out, t.out_offset) &&
        t.in_offset == t.out_offset) {
      out += fmt::format("  {}inputs and outputs:\n", chn);
      annex_table(out, ch.in, t.in_offset, true, true, p);
    } else {
      for (bool input : {true, false}) {
        const auto& bytes = input ? ch.in : ch.out;
        out += fmt::format("  {}{}:{}\n", chn, input ? "inputs" : "outputs", bytes.empty() ? " none" : "");
        if (!bytes.empty()) annex_table(out, bytes, input ? t.in_offset : t.out_offset, input, false, p);
      }
    }
    if (ch.window)
      out += fmt::format(
          "  {}register communication: control byte {} / status byte {}, value low byte {} / {}, high "
          "byte {} / {} (output / input image)\n",
          chn, ch.window->ctrl, ch.window->status, ch.window->out_lo, ch.window->in_lo, ch.window->out_hi,
          ch.window->in_hi);
    else if (t.type->has_registers)
      out += fmt::format("  {}no register communication: the control/status byte is not mapped\n", chn);
  }
  return out;
}

}  // namespace kscfg
