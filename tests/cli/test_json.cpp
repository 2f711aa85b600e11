// One JSON vocabulary (docs/json.md): every command's --json output parses, and the shared names
// mean the same everywhere. Every command of the tree is run here or listed as printing no JSON.
#include <fmt/format.h>

#include <catch2/catch.hpp>
#include <functional>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>

#include "app.hpp"
#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::TempDir;
using nlohmann::json;

namespace {

// Names docs/json.md forbids, each with what to say instead.
const std::map<std::string, std::string> kForbidden = {
    {"terminal", "position"}, {"from", "before"},     {"to", "after"},     {"differs", "at_default"},
    {"desc", "description"},  {"updated", "changed"}, {"written", "file"}, {"raw", "register_value"},
};

// Free text where a string of digits is legitimate (a version "10", a title, a USB serial).
const std::set<std::string> kText = {"version", "title",   "description",  "meaning", "identification",
                                     "serial",  "product", "manufacturer", "name",    "origin",
                                     "source",  "r6_text", "far_end"};

void check_names(const json& j, const std::string& where, std::vector<std::string>& bad) {
  auto fail = [&](const std::string& key, const std::string& why) { bad.push_back(where + "." + key + ": " + why); };
  if (j.is_array()) {
    for (std::size_t i = 0; i < j.size(); ++i) check_names(j[i], where + "[" + std::to_string(i) + "]", bad);
    return;
  }
  if (!j.is_object()) return;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& k = it.key();
    const json& v = it.value();
    if (auto f = kForbidden.find(k); f != kForbidden.end()) fail(k, "say '" + f->second + "'");
    if (v.is_string() && !kText.count(k) && std::regex_match(v.get<std::string>(), std::regex("-?[0-9]+")))
      fail(k, "a number in quotes: " + v.dump());
    if (k == "position" && !(v.is_number_unsigned() && v.get<unsigned>() >= 1)) fail(k, "not a position: " + v.dump());
    if (k == "channel" && !(v.is_number_unsigned() && v.get<unsigned>() >= 1)) fail(k, "not a channel: " + v.dump());
    if (k == "register" && !(v.is_number_unsigned() && v.get<unsigned>() <= 63)) fail(k, "not a register: " + v.dump());
    if (k == "type" && !(v.is_string() && std::regex_match(v.get<std::string>(),
                                                           std::regex("[A-Z]{2}[0-9]{3,4}[A-Z0-9-]*|CX-[A-Za-z0-9]+"))))
      fail(k, "not a terminal type: " + v.dump());
    if ((k == "changed" || k == "dry_run" || k == "verified" || k == "complex") && !v.is_boolean())
      fail(k, "not a bool: " + v.dump());
    if (k == "at_default" && !(v.is_boolean() || v.is_null())) fail(k, "not a bool or null: " + v.dump());
    if ((k == "unit" || k == "r8") && !(v.is_number_unsigned() || v.is_null())) fail(k, "not a number or null");
    if ((k == "port" || k == "state") && !v.is_string()) fail(k, "not a string");
    if (k == "terminal_count" && !v.is_number_unsigned()) fail(k, "not a number");
    if (k == "terminals" || k == "registers" || k == "params") {
      const char* key = k == "terminals" ? "position" : k == "registers" ? "register" : "name";
      if (!v.is_array()) fail(k, "not an array");
      else
        for (const auto& e : v)
          if (!e.is_object() || !e.contains(key)) fail(k, std::string("an element without '") + key + "'");
    }
    if (k == "values" && !v.is_object()) fail(k, "not an object of name: value");
    if (k == "before" && !j.contains("after")) fail(k, "'before' without 'after'");
    if (k == "after" && !j.contains("before")) fail(k, "'after' without 'before'");
    if (k == "hex") {
      if (!j.contains("value") || !j["value"].is_number_unsigned()) fail(k, "'hex' beside a value that is no number");
      else if (v != fmt::format("0x{:04X}", j["value"].get<unsigned>())) fail(k, "'hex' is not the value");
    }
    check_names(v, where + "." + k, bad);
  }
}

// Runs one command with --json; returns the parsed document after checking the vocabulary.
json run_json(const std::function<Run(std::vector<std::string>)>& run, const std::vector<std::string>& args,
              int want_rc = 0) {
  std::vector<std::string> a = {"--json"};
  a.insert(a.end(), args.begin(), args.end());
  Run r = run(a);
  std::string line;
  for (const auto& s : args) line += " " + s;
  INFO("kscfg --json" << line << "\nstdout: " << r.out << "\nstderr: " << r.err);
  REQUIRE(r.rc == want_rc);
  json j;
  REQUIRE_NOTHROW(j = json::parse(r.out));
  std::vector<std::string> bad;
  check_names(j, "$", bad);
  for (const auto& b : bad) FAIL_CHECK(b);
  return j;
}

std::set<std::string> command_paths() {
  auto app = kscfg::cli::build_app();
  std::set<std::string> out;
  std::function<void(const CLI::App*, std::string)> walk = [&](const CLI::App* a, std::string path) {
    for (const CLI::App* s : a->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); })) {
      std::string p = path.empty() ? s->get_name() : path + " " + s->get_name();
      if (s->get_subcommands([](const CLI::App*) { return true; }).empty()) out.insert(p);
      walk(s, p);
    }
  };
  walk(&app->cli, "");
  return out;
}

// Commands whose product is text, not data (docs/json.md says so).
const std::set<std::string> kNoJson = {"completion", "manpage", "help", "serial term"};

}  // namespace

TEST_CASE("every command's JSON uses the shared names", "[json][cli]") {
  Emu emu;
  TempDir d;
  std::set<std::string> covered;
  auto run = [&](std::vector<std::string> a) { return emu(a); };
  auto J = [&](const std::string& path, std::vector<std::string> args, int rc = 0) {
    covered.insert(path);
    return run_json(run, args, rc);
  };

  json info = J("info", {"info"});
  CHECK(info["terminals"].size() == 7);
  CHECK(info["terminals"][0]["r8"] == 6001);
  CHECK(info["terminals"][0]["image"]["inputs"]["offset"] == 0);
  CHECK(info["unit"].is_null());
  json one = J("info", {"-t", "1", "info"});
  CHECK(one["registers"][0]["register"] == 8);
  CHECK(one["registers"][0]["value"] == 6001);

  json rd = J("read", {"read", "R32", "R8"});
  CHECK(rd["position"] == 1);
  CHECK(rd["channel"] == 1);
  CHECK(rd["registers"][0]["values"]["baud"] == 9600);

  json wr = J("write", {"write", "R32", "7"});
  CHECK(wr["before"] == 6);
  CHECK(wr["after"] == 7);
  CHECK(wr["changed"] == true);
  CHECK(J("write", {"write", "R32", "7"})["changed"] == false);

  json dump = J("dump", {"dump"});
  CHECK(dump["registers"][32]["at_default"] == false);
  CHECK(dump["registers"][33]["at_default"] == true);

  CHECK(J("unlock", {"unlock"})["unlocked"] == true);
  CHECK(J("lock", {"lock"})["unlocked"] == false);

  json show = J("show", {"show"});
  bool saw_baud = false;
  for (const auto& p : show["params"])
    if (p["name"] == "baud") {
      saw_baud = true;
      CHECK(p["value"] == 19200);
      CHECK(p["default"] == 9600);
      CHECK(p["at_default"] == false);
    }
  CHECK(saw_baud);
  json get = J("get", {"get", "baud", "frame"});
  CHECK(get["values"]["baud"] == 19200);
  CHECK(get["values"]["frame"] == "8N1");

  json set = J("set", {"set", "baud", "4800"});
  CHECK(set["changed"] == true);
  CHECK(set["params"][0]["before"] == 19200);
  CHECK(set["params"][0]["after"] == 4800);

  json reset = J("reset", {"-t", "1", "reset", "-y"});
  CHECK(reset["changed"] == true);
  CHECK(reset["method"] == "defaults");
  CHECK(J("reset", {"-t", "1", "reset", "-y"})["changed"] == false);
  // R7 = 0x7000 (KL6031): "changed" only when a register really changed.
  REQUIRE(emu({"-t", "3", "write", "R32", "0x0007"}).rc == 0);
  json r7 = J("reset", {"-t", "3", "reset", "-y"});
  CHECK(r7["method"] == "r7");
  CHECK(r7["changed"] == true);
  CHECK(J("reset", {"-t", "3", "reset", "-y"})["changed"] == false);

  CHECK(J("decode", {"decode", "status", "0x35", "-T", "KL6001"})["bits"]["IA"] == 1);
  CHECK(J("catalog", {"catalog"})["types"].size() > 100);
  CHECK(J("catalog", {"catalog", "KL6001"})["params"].size() > 3);

  std::string bk = d.file("b.toml"), want = d.file("want.toml");
  CHECK(J("backup", {"backup", bk})["terminal_count"] == 7);
  std::string text = read_text(bk);
  // The backup writes baud and the raw R32 it lives in: an edit changes both (they must agree).
  text.replace(text.find("baud = 9600"), 11, "baud = 2400");
  kscfg::test::write_text(want, text.replace(text.find("R32 = 0x0006"), 12, "R32 = 0x0004"));
  json diff = J("diff", {"diff", want}, 1);
  CHECK(diff["dry_run"] == true);
  CHECK(diff["backup"].is_null());
  CHECK(diff["terminals"][0]["params"][0]["before"] == 9600);
  CHECK(diff["terminals"][0]["params"][0]["after"] == 2400);
  json apply = J("apply", {"apply", "--backup", d.file("undo.toml"), want});
  CHECK(apply["changed"] == true);
  CHECK(apply["dry_run"] == false);
  CHECK(apply["backup"] == d.file("undo.toml"));
  CHECK(apply["port"] == "emu:" + emu.state);
  CHECK(J("restore", {"restore", "--backup", d.file("undo2.toml"), bk})["changed"] == true);

  J("map", {"map"});
  CHECK(J("map", {"map", "--list-couplers"})["couplers"].size() >= 10);
  CHECK(J("station init", {"station", "init", d.file("s.toml")})["file"] == d.file("s.toml"));
  CHECK(J("station check", {"station", "check", d.file("s.toml")})["coupler"] == "BK9000");

  CHECK(J("serial init", {"serial", "init"})["position"] == 1);
  CHECK(J("serial send", {"serial", "send", "AB"})["sent"] == 2);
  CHECK(J("serial recv", {"serial", "recv", "--count", "2"})["received"] == 2);
  CHECK(J("serial status", {"serial", "status"})["type"] == "KL6001");
  CHECK(J("serial line", {"serial", "line"})["frame"] == "8N1");

  J("ports", {"ports"});
  CHECK(J("emu path", {"emu", "path"})["state"] == emu.state);
  CHECK(J("emu fault", {"emu", "fault", "--clear"})["changed"] == true);
  CHECK(J("emu encoder", {"emu", "encoder", "--step", "1"})["position"] == 2);
  CHECK(J("data", {"-t", "2", "data", "--once"})["counter"] == 4);  // one channel: one JSON line
  CHECK(J("emu reset", {"emu", "reset"})["terminal_count"] == 7);
  CHECK(J("emu restart", {"emu", "restart"})["changed"] == false);
  // An analog input with a processing chain: what it measures.
  kscfg::test::write_text(d.file("rtd.toml"), "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL3202\"\n");
  CHECK(J("emu reset", {"emu", "reset", "--station", d.file("rtd.toml")})["terminal_count"] == 1);
  CHECK(J("emu input", {"-t", "1", "emu", "input", "21.5"})["reading"] == "21.5 °C");

  // A Modbus link: scan, and the unit of the provisioning commands.
  kscfg::test::Server srv(d.file("served.json"), {"--json", "--tcp", "127.0.0.1:0"}, d.file("serve.err"));
  json served = json::parse(srv.uri);
  covered.insert("serve");
  REQUIRE(served["port"].is_string());
  std::string port = served["port"];
  auto tcp = [&](std::vector<std::string> a) {
    a.insert(a.begin(), {"--port", port});
    return kscfg::test::run_kscfg(a);
  };
  covered.insert("scan");
  json scan = run_json(tcp, {"scan"});
  CHECK(scan["terminals"][0]["type"] == "KL6001");
  std::string tbk = d.file("tcp.toml");
  REQUIRE(tcp({"backup", tbk}).rc == 0);
  json tdiff = run_json(tcp, {"diff", tbk});
  CHECK(tdiff["unit"] == 1);
  CHECK(tdiff["changed"] == false);
  // kscfg coupler over Modbus: the watchdog registers, 0x1123 not served by serve.
  covered.insert("coupler");
  json cp = run_json(tcp, {"coupler"});
  CHECK(cp["protocol"] == "modbus");
  REQUIRE(cp["settings"].size() == 4);
  CHECK(cp["settings"][0]["name"] == "watchdog");
  CHECK(cp["settings"][0]["register_value"] == 1000);
  CHECK(cp["settings"][2]["register_value"] == 1);
  CHECK(cp["settings"][3]["register_value"].is_null());
  CHECK(cp["settings"][3]["value"] == "not served");
  CHECK(cp["settings"][0]["source"].get<std::string>().rfind("https://infosys.beckhoff.com/", 0) == 0);

  for (const auto& p : command_paths()) {
    INFO(p);
    CHECK((covered.count(p) || kNoJson.count(p)));
  }
}

TEST_CASE("with --json an error is one JSON object on stderr and nothing on stdout", "[json][cli]") {
  Emu emu;
  for (const std::vector<std::string>& args : {std::vector<std::string>{"--json", "read", "R99"},
                                               {"read", "R8", "--json", "--jsn"},
                                               {"--json", "frobnicate"},
                                               {"--json", "-t", "99", "info"},
                                               {"--json", "diff", "/nonexistent.toml"}}) {
    Run r = emu(args);
    INFO(r.err);
    CHECK(r.rc != 0);
    CHECK(r.out.empty());
    CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
    json j;
    REQUIRE_NOTHROW(j = json::parse(r.err));
    CHECK(j["error"].is_string());
    CHECK(j["exit"] == r.rc);
    if (j.contains("hint")) CHECK(j["hint"].is_string());
  }
}
