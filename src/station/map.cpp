#include "kscfg/station/map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <iterator>
#include <map>
#include <set>

#include "kscfg/base/error.hpp"

namespace kscfg {

std::vector<unsigned> mapping_registers(const TerminalType& type) {
  std::set<unsigned> regs;
  for (const auto& f : type.images) {
    if (f.when) regs.insert(f.when->reg);
    for (const auto* list : {&f.out, &f.in})
      for (const auto& e : *list)
        if (e.count_register) regs.insert(*e.count_register);
  }
  return {regs.begin(), regs.end()};
}

std::size_t image_limit(const CouplerProfile& p, bool input) {
  std::size_t n = input ? p.max_in_bytes : p.max_out_bytes;
  if (n == 0 && p.modbus) n = kModbusImageBytes;
  return n;
}

void check_image_limits(const StationLayout& L, const CouplerProfile& p) {
  for (bool input : {true, false}) {
    std::size_t size = input ? L.in_bytes : L.out_bytes;
    std::size_t limit = image_limit(p, input);
    if (limit && size > limit)
      throw Error(Exit::usage,
                  fmt::format("the station needs {} {} bytes, more than the {} takes ({} bytes)", size,
                              input ? "input" : "output", p.name, limit),
                  "remove terminals, or map fewer bytes (e.g. complete evaluation off, fewer KL6001 data bytes)");
  }
}

std::vector<MapEntry> map_entries(const StationLayout& L, bool input) {
  std::vector<MapEntry> v;
  std::size_t complex = input ? L.complex_in : L.complex_out;
  for (const auto& t : L.terminals) {
    if (t.complex) {
      for (std::size_t c = 0; c < t.channels.size(); ++c) {
        const auto& bytes = input ? t.channels[c].in : t.channels[c].out;
        if (bytes.empty()) continue;
        MapEntry e;
        e.input = input;
        e.offset = bytes.front().offset;
        e.size = bytes.back().offset + 1 - bytes.front().offset;
        e.position = t.position;
        e.type = t.type->type;
        e.channel = static_cast<unsigned>(c + 1);
        e.bytes = bytes;
        v.push_back(std::move(e));
      }
    } else {
      unsigned bits = input ? t.bits_in : t.bits_out;
      if (!bits) continue;
      std::size_t abs = input ? t.in_bit : t.out_bit;
      MapEntry e;
      e.input = input;
      e.digital = true;
      e.offset = abs / 8;
      e.bit = static_cast<unsigned>(abs % 8);
      e.size = bits;
      e.bit_offset = abs - complex * 8;
      e.position = t.position;
      e.type = t.type->type;
      v.push_back(std::move(e));
    }
  }
  std::stable_sort(v.begin(), v.end(), [](const MapEntry& a, const MapEntry& b) {
    return a.offset * 8 + a.bit < b.offset * 8 + b.bit;
  });
  return v;
}

std::string bit_range(const MapEntry& e) {
  std::size_t first = e.offset * 8 + e.bit, last = first + e.size - 1;
  if (e.size == 1) return fmt::format("{}.{}", first / 8, first % 8);
  return fmt::format("{}.{}-{}.{}", first / 8, first % 8, last / 8, last % 8);
}

namespace {

const char* on_off(bool b) { return b ? "on" : "off"; }

std::string settings_text(const StationLayout& L) {
  return fmt::format("complete evaluation {}, Motorola format {}, word alignment {}",
                     on_off(L.settings.complete_evaluation), on_off(L.settings.motorola),
                     on_off(L.settings.word_alignment));
}

std::string reg_text(unsigned r) { return fmt::format("0x{:04X}", r); }

unsigned base_register(bool input) { return input ? kModbusInputBase : kModbusOutputBase; }

std::string register_range(bool input, std::size_t first_byte, std::size_t last_byte) {
  unsigned a = base_register(input) + static_cast<unsigned>(first_byte / 2);
  unsigned b = base_register(input) + static_cast<unsigned>(last_byte / 2);
  return a == b ? reg_text(a) : reg_text(a) + "-" + reg_text(b);
}

std::string byte_range(std::size_t a, std::size_t b) { return a == b ? fmt::format("{}", a) : fmt::format("{}-{}", a, b); }

std::string bit_numbers(const MapEntry& e) {
  std::size_t a = e.bit_offset, b = e.bit_offset + e.size - 1;
  return fmt::format("{} {}", e.input ? (a == b ? "discrete input" : "discrete inputs") : (a == b ? "coil" : "coils"),
                     byte_range(a, b));
}

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
  rows.push_back({"offset", "size", "pos", "type", "ch", p.modbus ? "register" : "", "content"});
  for (const auto& e : entries) {
    Row r;
    if (e.digital) {
      r.offset = fmt::format("{}.{}", e.offset, e.bit);
      r.size = fmt::format("{} bit", e.size);
      r.ch = "-";
      std::size_t last = e.offset * 8 + e.bit + e.size - 1;
      r.reg = p.modbus ? register_range(input, e.offset, last / 8) : "";
      r.content = "bits " + bit_range(e);
      if (p.modbus) r.content += " (" + bit_numbers(e) + ")";
    } else {
      r.offset = fmt::format("{}", e.offset);
      r.size = fmt::format("{}", e.size);
      r.ch = fmt::format("{}", e.channel);
      r.reg = p.modbus ? register_range(input, e.offset, e.offset + e.size - 1) : "";
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
    if (p.modbus) line += fmt::format("{:<{}}  ", r.reg, w[5]);
    line += r.content;
    while (!line.empty() && line.back() == ' ') line.pop_back();
    out += line + '\n';
  }
}

std::string terminal_header(const TerminalImage& t) {
  return fmt::format("Terminal {}: {} ({})", t.position, t.type->type, t.type->title);
}

}  // namespace

std::string render_table(const StationLayout& L, const CouplerProfile& p) {
  std::string out = fmt::format("{} ({}{}): {}\n", p.name, p.family, p.modbus ? ", Modbus" : "", settings_text(L));
  table_section(out, L, p, true);
  table_section(out, L, p, false);
  std::vector<std::string> none;
  for (const auto& t : L.terminals)
    if (!t.complex && !t.bits_in && !t.bits_out) none.push_back(fmt::format("{} {}", t.position, t.type->type));
  if (!none.empty()) {
    out += "\nNo process image:";
    for (std::size_t i = 0; i < none.size(); ++i) out += (i ? ", " : " ") + none[i];
    out += '\n';
  }
  if (p.modbus)
    out += fmt::format("\nModbus: input register n = input bytes 2n (low) and 2n+1 (high) at 0x{:04X}+n; outputs at "
                       "0x{:04X}+n; discrete inputs and coils count from the first digital bit.\n",
                       kModbusInputBase, kModbusOutputBase);
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
  std::string head = fmt::format("    {:<10}  {:<{}}  {:<{}}  {}", "I/O offset", "high byte", wh, "low byte", wl,
                                 "image bytes");
  if (p.modbus) head += both ? "   registers (in / out)" : "   register";
  out += head + '\n';
  for (const auto& r : rows) {
    std::size_t b0 = base + 2 * r.offset;
    std::string line = fmt::format("    {:<10}  {:<{}}  {:<{}}  {:<11}", r.offset, r.high, wh, r.low, wl,
                                   byte_range(b0, b0 + 1));
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
          out += fmt::format(" (register {}, {})", register_range(input, e.offset, (e.offset * 8 + e.bit + e.size - 1) / 8),
                             bit_numbers(e));
        out += '\n';
      }
    }
    return out;
  }
  out += fmt::format("  format {}; inputs {} bytes at {}, outputs {} bytes at {}\n", t.format, t.in_size, t.in_offset,
                     t.out_size, t.out_offset);
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
      out += fmt::format("  {}register communication: control byte {} / status byte {}, value low byte {} / {}, high "
                         "byte {} / {} (output / input image)\n",
                         chn, ch.window->ctrl, ch.window->status, ch.window->out_lo, ch.window->in_lo,
                         ch.window->out_hi, ch.window->in_hi);
    else if (t.type->has_registers)
      out += fmt::format("  {}no register communication: the control/status byte is not mapped\n", chn);
  }
  return out;
}

std::string render_grid(const StationLayout& L, bool color) {
  static const char* palette[] = {"30;46", "30;43", "30;42", "30;45", "37;44", "37;41", "30;47", "30;106",
                                  "30;103", "30;102", "30;105", "30;104"};
  auto paint = [&](unsigned pos, const std::string& text, bool dim) {
    if (!color || pos == 0) return text;
    return fmt::format("\x1b[{}{}m{}\x1b[0m", palette[(pos - 1) % std::size(palette)], dim ? ";2" : "", text);
  };
  std::string out;
  for (bool input : {true, false}) {
    std::size_t n = input ? L.in_bytes : L.out_bytes;
    // Owner of each byte: position, reserved flag; digital bytes may be shared (0 = several).
    std::vector<unsigned> owner(n, 0);
    std::vector<char> kind(n, ' ');  // ' ' unused, 'c' complex, 'r' reserved, 'd' digital, '*' shared digital
    for (const auto& e : map_entries(L, input)) {
      if (e.digital) {
        std::size_t first = e.offset * 8 + e.bit, last = first + e.size - 1;
        for (std::size_t b = first / 8; b <= last / 8 && b < n; ++b) {
          if (kind[b] == 'd' && owner[b] != e.position) {
            kind[b] = '*';
            owner[b] = 0;
          } else if (kind[b] != '*') {
            kind[b] = 'd';
            owner[b] = e.position;
          }
        }
      } else {
        for (const auto& b : e.bytes) {
          if (b.offset >= n) continue;
          owner[b.offset] = e.position;
          kind[b.offset] = b.index < 0 ? 'r' : 'c';
        }
      }
    }
    out += fmt::format("{} ({} bytes)\n", input ? "Inputs" : "Outputs", n);
    for (std::size_t row = 0; row < n; row += 16) {
      out += fmt::format("  {:>4} ", row);
      for (std::size_t b = row; b < std::min(n, row + 16); ++b) {
        std::string cell;
        switch (kind[b]) {
          case 'c': cell = fmt::format("{:>3}", owner[b]); break;
          case 'r': cell = "  ."; break;
          case 'd': cell = fmt::format("{:>2}d", owner[b]); break;
          case '*': cell = "  *"; break;
          default: cell = "  -"; break;
        }
        out += paint(owner[b], cell, kind[b] == 'r');
      }
      out += '\n';
    }
  }
  out += "Legend:";
  for (const auto& t : L.terminals)
    if (t.complex || t.bits_in || t.bits_out)
      out += " " + paint(t.position, fmt::format("{} {}", t.position, t.type->type), false);
  out += "; . reserved, Nd digital bits of N, * digital bits of several terminals, - unused\n";
  return out;
}

nlohmann::json map_json(const StationLayout& L, const CouplerProfile& p) {
  using nlohmann::json;
  json j;
  j["coupler"] = p.name;
  j["family"] = p.family;
  j["modbus"] = p.modbus;
  j["settings"] = {{"complete_evaluation", L.settings.complete_evaluation},
                   {"motorola", L.settings.motorola},
                   {"word_alignment", L.settings.word_alignment}};
  for (bool input : {true, false}) {
    json img = {{"bytes", input ? L.in_bytes : L.out_bytes},
                {"complex_bytes", input ? L.complex_in : L.complex_out},
                {"digital_bits", input ? L.digital_in_bits : L.digital_out_bits}};
    std::size_t limit = image_limit(p, input);
    img["limit"] = limit ? json(limit) : json(nullptr);
    j[input ? "inputs" : "outputs"] = img;
  }
  auto byte_json = [&](const ImageByte& b, bool input) {
    json x = {{"offset", b.offset}, {"name", b.name}, {"reserved", b.index < 0}};
    if (p.modbus) {
      x["register"] = base_register(input) + b.offset / 2;
      x["half"] = b.offset % 2 ? "high" : "low";
    }
    return x;
  };
  json terms = json::array();
  for (const auto& t : L.terminals) {
    json x = {{"position", t.position}, {"type", t.type->type}, {"family", t.type->family}, {"format", t.format},
              {"complex", t.complex}};
    if (t.complex) {
      x["inputs"] = {{"offset", t.in_offset}, {"size", t.in_size}};
      x["outputs"] = {{"offset", t.out_offset}, {"size", t.out_size}};
      json chans = json::array();
      for (std::size_t c = 0; c < t.channels.size(); ++c) {
        const auto& ch = t.channels[c];
        json cj = {{"channel", c + 1}, {"inputs", json::array()}, {"outputs", json::array()}};
        for (const auto& b : ch.in) cj["inputs"].push_back(byte_json(b, true));
        for (const auto& b : ch.out) cj["outputs"].push_back(byte_json(b, false));
        if (ch.window)
          cj["register_window"] = {{"control", ch.window->ctrl}, {"status", ch.window->status},
                                   {"out_lo", ch.window->out_lo}, {"out_hi", ch.window->out_hi},
                                   {"in_lo", ch.window->in_lo},   {"in_hi", ch.window->in_hi}};
        else
          cj["register_window"] = nullptr;
        chans.push_back(std::move(cj));
      }
      x["channels"] = std::move(chans);
    } else if (t.bits_in || t.bits_out) {
      for (bool input : {true, false}) {
        unsigned bits = input ? t.bits_in : t.bits_out;
        if (!bits) continue;
        for (const auto& e : map_entries(L, input)) {
          if (e.position != t.position) continue;
          json d = {{"byte", e.offset}, {"bit", e.bit}, {"bits", bits}, {"range", bit_range(e)},
                    {"digital_bit", e.bit_offset}};
          if (p.modbus) {
            d["register"] = base_register(input) + e.offset / 2;
            d["register_bit"] = (e.offset % 2) * 8 + e.bit;
          }
          x[input ? "inputs" : "outputs"] = d;
        }
      }
    }
    terms.push_back(std::move(x));
  }
  j["terminals"] = std::move(terms);
  return j;
}

}  // namespace kscfg
