// Every place in the CLI text that names the links names ADS too.
#include <catch2/catch.hpp>
#include <string>

#include "support.hpp"

using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;

TEST_CASE("the links are named with ADS among them in --help, the man page and the Ansible modules", "[docs]") {
  const std::string links = "Modbus TCP, Modbus RTU or ADS";
  Run help = run_kscfg({"--help"});
  REQUIRE(help.rc == 0);
  // --help wraps its text: compare it with the lines joined.
  std::string joined;
  for (char c : help.out) joined += c == '\n' ? ' ' : c;
  CHECK_THAT(joined, Catch::Contains("emulator, Modbus TCP, Modbus RTU, ADS or CANopen."));
  std::string man = read_text(std::string(KSCFG_SOURCE_DIR) + "/man/kscfg.1");
  auto description = man.substr(man.find(".SH DESCRIPTION"), 800);
  CHECK_THAT(description, Catch::Contains("the embedded emulator (default), " + links + "; on a CANopen coupler"));
  std::string data_man = man.substr(man.find(".SS \"kscfg data"));
  data_man = data_man.substr(0, data_man.find(".SS \"kscfg", 5));
  CHECK_THAT(data_man, Catch::Contains("Modbus TCP, Modbus RTU and ADS"));
  const std::string modules =
      std::string(KSCFG_SOURCE_DIR) + "/contrib/ansible/ansible_collections/kscfg/bus/plugins/modules/";
  CHECK_THAT(read_text(modules + "kscfg_station.py"), Catch::Contains("(" + links + ")"));
  CHECK_THAT(read_text(modules + "kscfg_facts.py"), Catch::Contains("emulator, " + links));
}
