#include "fixtures.hpp"

#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <thread>

#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg::test {

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

Station::Station(const std::string& p) : port(p.empty() ? "emu:" + state : p) {
  env["KSCFG_PORT"] = port;
  env["XDG_STATE_HOME"] = dir.file("xdg");
}

void Station::emulate(const std::string& toml) {
  if (toml.empty()) return;
  write_text(dir.file("station.toml"), toml);
  Run r = (*this)({"emu", "reset", "--station", dir.file("station.toml")});
  REQUIRE(r.rc == 0);
}

std::string Station::snapshot() const {
  Run b = (*this)({"backup"});
  REQUIRE(b.rc == 0);
  return b.out;
}

bool all_channels_locked(const std::string& state, double timeout_s) {
  return wait_for(
      [&] {
        try {
          auto j = nlohmann::json::parse(read_text(state));
          for (const auto& c : j["channels"])
            if (c["registers"][31] == 0x1235) return false;
          return true;
        } catch (...) {
          return false;
        }
      },
      timeout_s);
}

std::vector<std::uint8_t> modbus_image(const std::string& uri, std::uint16_t at, std::size_t words) {
  kscfg::ModbusClient c(kscfg::modbus_target(kscfg::parse_port_uri(uri), uri), {});
  std::vector<std::uint8_t> b;
  for (auto v : c.read(at, words))
    b.insert(b.end(), {static_cast<std::uint8_t>(v & 0xFF), static_cast<std::uint8_t>(v >> 8)});
  return b;
}

std::string shell_output(const std::string& command) {
  std::string out;
  FILE* p = popen(command.c_str(), "r");
  if (!p) return out;
  char buf[4096];
  std::size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
  pclose(p);
  return out;
}

Tmux::Tmux(const std::string& name) : tmux("tmux -L kscfg-" + name + "-" + std::to_string(getpid()) + " ") {
  if (std::system("command -v tmux >/dev/null 2>&1") != 0)
    FAIL("tmux is not installed (the README's test command installs it)");
}

Tmux::~Tmux() { kill_server(); }

void Tmux::start(const std::string& command, int columns, int rows) const {
  shell_output(tmux + "new-session -d -s t -x " + std::to_string(columns) + " -y " + std::to_string(rows) + " " +
               shell_quote(command));
}

void Tmux::send_keys(const std::string& keys) const { shell_output(tmux + "send-keys -t t " + keys); }

std::string Tmux::pane() const { return shell_output(tmux + "capture-pane -p -t t 2>/dev/null"); }

bool Tmux::wait_for(const std::string& text, double timeout_s) const {
  return wait_for([&](const std::string& screen) { return screen.find(text) != std::string::npos; }, timeout_s);
}

bool Tmux::wait_for(const std::function<bool(const std::string&)>& holds, double timeout_s) const {
  auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    if (holds(pane())) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

void Tmux::kill_server() const { shell_output(tmux + "kill-server 2>/dev/null"); }

}  // namespace kscfg::test
