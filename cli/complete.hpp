// `kscfg __complete -- WORDS...`: what the shell should offer for the last word, offline, from the
// command tree, the catalog and the station (--station FILE, or the emulator's state for an emu
// port; a Modbus port is never opened). The bash, zsh and fish scripts of `kscfg completion` ask it.
//
// Output, one per line: "VALUE" or "VALUE<TAB>DESCRIPTION"; ":files" / ":dirs" ask the shell for
// its own file or directory completion. A VALUE ending in ':' or '/' wants no space after it.
#pragma once
#include <string>
#include <vector>

#include "app.hpp"

namespace kscfg::cli {

struct Candidate {
  std::string value, description;
};

struct Completions {
  std::vector<Candidate> items;
  bool files = false, dirs = false;
};

// `words`: the command line up to the cursor, the program name first and the word being completed
// last (empty when the cursor follows a space).
Completions complete_words(const App& a, Context& ctx, const std::vector<std::string>& words);

std::string completion_text(const Completions& c);

}  // namespace kscfg::cli
