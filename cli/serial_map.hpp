// serial term's character maps, as picocom names them: --omap for typed bytes on their way to
// the line, --imap for received bytes on their way to the screen.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace kscfg::cli {

enum SerialMap : unsigned {
  kMapCrLf = 1u << 0,    // crlf: CR -> LF
  kMapCrCrLf = 1u << 1,  // crcrlf: CR -> CR LF
  kMapIgnCr = 1u << 2,   // igncr: CR dropped
  kMapLfCr = 1u << 3,    // lfcr: LF -> CR
  kMapLfCrLf = 1u << 4,  // lfcrlf: LF -> CR LF
  kMapIgnLf = 1u << 5,   // ignlf: LF dropped
  kMapBsDel = 1u << 6,   // bsdel: BS -> DEL
  kMapDelBs = 1u << 7,   // delbs: DEL -> BS
};

// "crlf,delbs" -> flags; "" and "none" -> 0. Error(usage) names an unknown map and lists them.
unsigned parse_serial_map(const std::string& spec, const std::string& option);
// "crlf,delbs" or "none".
std::string serial_map_text(unsigned flags);
// Every map name (completion, help).
std::vector<std::string> serial_map_names();
// The bytes after the map (CR first: igncr, then crcrlf, then crlf; LF alike).
std::vector<std::uint8_t> apply_serial_map(unsigned flags, std::span<const std::uint8_t> in);

}  // namespace kscfg::cli
