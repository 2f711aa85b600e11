// The map as JSON (kscfg --json map).
#include <fmt/format.h>

#include "kscfg/station/map.hpp"
#include "map_detail.hpp"

namespace kscfg {

using namespace map_detail;

namespace {

using nlohmann::json;

json ads_json(bool input, std::size_t offset) {
  return json{
      {"ads_port", kAdsImagePort}, {"index_group", input ? kAdsInputGroup : kAdsOutputGroup}, {"index_offset", offset}};
}

json byte_json(const CouplerProfile& p, const ImageByte& b, bool input) {
  json x = {{"offset", b.offset}, {"name", b.name}, {"reserved", b.index < 0}};
  if (p.modbus) {
    x["modbus_register"] = base_register(input) + b.offset / 2;
    x["half"] = b.offset % 2 ? "high" : "low";
  }
  if (p.ads) x["ads"] = ads_json(input, b.offset);
  return x;
}

// A complex terminal: its byte ranges, and each channel's bytes and register window.
void complex_json(const TerminalImage& t, const CouplerProfile& p, json& x) {
  x["inputs"] = {{"offset", t.in_offset}, {"size", t.in_size}};
  x["outputs"] = {{"offset", t.out_offset}, {"size", t.out_size}};
  if (p.ads) {
    x["inputs"]["ads"] = ads_json(true, t.in_offset);
    x["outputs"]["ads"] = ads_json(false, t.out_offset);
  }
  json chans = json::array();
  for (std::size_t c = 0; c < t.channels.size(); ++c) {
    const auto& ch = t.channels[c];
    json cj = {{"channel", c + 1}, {"inputs", json::array()}, {"outputs", json::array()}};
    for (const auto& b : ch.in) cj["inputs"].push_back(byte_json(p, b, true));
    for (const auto& b : ch.out) cj["outputs"].push_back(byte_json(p, b, false));
    if (ch.window)
      cj["register_window"] = {{"control", ch.window->ctrl},  {"status", ch.window->status},
                               {"out_lo", ch.window->out_lo}, {"out_hi", ch.window->out_hi},
                               {"in_lo", ch.window->in_lo},   {"in_hi", ch.window->in_hi}};
    else cj["register_window"] = nullptr;
    chans.push_back(std::move(cj));
  }
  x["channels"] = std::move(chans);
}

// A digital terminal: where its bits are, each direction.
void digital_json(const StationLayout& L, const TerminalImage& t, const CouplerProfile& p, json& x) {
  for (bool input : {true, false}) {
    unsigned bits = input ? t.bits_in : t.bits_out;
    if (!bits) continue;
    for (const auto& e : map_entries(L, input)) {
      if (e.position != t.position) continue;
      json d = {
          {"byte", e.offset}, {"bit", e.bit}, {"bits", bits}, {"range", bit_range(e)}, {"digital_bit", e.bit_offset}};
      if (p.modbus) {
        d["modbus_register"] = base_register(input) + e.offset / 2;
        d["modbus_bit"] = (e.offset % 2) * 8 + e.bit;
      }
      if (p.ads) d["ads"] = ads_json(input, e.offset);
      x[input ? "inputs" : "outputs"] = d;
    }
  }
}

json terminal_json(const StationLayout& L, const TerminalImage& t, const CouplerProfile& p) {
  json x = {{"position", t.position},
            {"type", t.inferred ? json(nullptr) : json(t.type->type)},
            {"family", t.type->family},
            {"format", t.format},
            {"complex", t.complex}};
  if (t.inferred) {
    x["digital"] = digital_label(t);
    x["fits"] = t.fits;
  }
  if (t.complex) complex_json(t, p, x);
  else if (t.bits_in || t.bits_out) digital_json(L, t, p, x);
  return x;
}

}  // namespace

nlohmann::json map_json(const StationLayout& L, const CouplerProfile& p) {
  json j;
  j["coupler"] = p.name;
  j["family"] = p.family;
  j["modbus"] = p.modbus;
  j["ads"] = p.ads;
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
  json terms = json::array();
  for (const auto& t : L.terminals) terms.push_back(terminal_json(L, t, p));
  j["terminals"] = std::move(terms);
  return j;
}

}  // namespace kscfg
