// kscfg data with -t naming a type or several terminals: the live view shows what -t selects, and
// data force takes a type that selects one terminal and refuses one that selects several.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::Run;
using kscfg::test::write_text;
using nlohmann::json;

namespace {

std::set<unsigned> positions(const std::string& out) {
  std::set<unsigned> v;
  std::istringstream in(out);
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) v.insert(json::parse(line).at("position").get<unsigned>());
  return v;
}

}  // namespace

TEST_CASE("data -t TYPE or a list shows the terminals it selects, and data force takes a type that selects one",
          "[data][cli]") {
  // -t KL2134, -t 2,4 and -t 2-3 were taken as no -t at all: the live view showed every terminal, and
  // data force said "give -t POS" for a type the station has once.
  Emu emu;
  write_text(emu.dir.file("st.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\n"
             "type = \"KL2134\"\n[[terminal]]\ntype = \"KL2124\"\n[[terminal]]\ntype = \"KL9010\"\n");
  REQUIRE(emu({"emu", "reset", "--station", emu.dir.file("st.toml")}).rc == 0);
  Run r = emu({"--json", "-t", "KL2134", "data", "--once"});
  CHECK(r.rc == 0);
  CHECK(positions(r.out) == std::set<unsigned>{2, 3});
  r = emu({"--json", "-t", "2,4", "data", "--once"});
  CHECK(positions(r.out) == std::set<unsigned>{2, 4});
  r = emu({"--json", "-t", "KL2124", "data", "--once"});
  CHECK(positions(r.out) == std::set<unsigned>{4});
  r = emu({"-t", "KL2124", "data", "force", "2=1", "--yes", "--no-restore"});
  CHECK(r.rc == 0);
  r = emu({"--json", "-t", "4", "data", "--once"});
  CHECK(json::parse(r.out).at("outputs") == json::array({0, 1, 0, 0}));
  r = emu({"-t", "KL2134", "data", "force", "1=1", "--yes", "--no-restore"});
  CHECK(r.rc == 2);
  CHECK_THAT(r.err, Catch::Contains("-t KL2134 selects 2 terminals (2, 3)"));
  r = emu({"--json", "-t", "2-3", "data", "--once"});
  CHECK(r.out.find("[1,") == std::string::npos);  // nothing forced there
}
