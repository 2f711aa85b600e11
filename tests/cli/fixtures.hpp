// Fixtures the CLI tests share: a station of one test's own, what serve's state file and a Modbus
// client see of a served coupler, and kscfg on a tmux screen.
#pragma once
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "support.hpp"

namespace kscfg::test {

// An emulator (Emu: its own state file, KSCFG_PORT) whose commands also keep their journals,
// backups and sessions to themselves: XDG_STATE_HOME is dir/xdg. With `port` ("tcp://...", a
// serve's URI) the commands go there instead of to the emulator.
struct Station : Emu {
  explicit Station(const std::string& port = "");
  std::string port;
  std::string file(const std::string& name) const { return dir.file(name); }
  // Makes the emulator the station `toml` describes (emu reset --station); "" leaves the default.
  void emulate(const std::string& toml);
  // `backup` to stdout: the station's settings, to compare before and after.
  std::string snapshot() const;
};

// Whether no channel of the emulator state file `state` holds R31 = 0x1235 (unlocked), waited for
// up to `timeout_s` seconds: serve saves its state a few ms after a change.
bool all_channels_locked(const std::string& state, double timeout_s = 10);

// `words` 16-bit registers of the coupler behind `uri` from Modbus address `at` (another Modbus
// client), as bytes, low byte first. Throws when the coupler does not answer.
std::vector<std::uint8_t> modbus_image(const std::string& uri, std::uint16_t at, std::size_t words);

// `s` as one word of a shell command line, in single quotes.
std::string shell_quote(const std::string& s);

// What `command` (through /bin/sh) writes to stdout.
std::string shell_output(const std::string& command);

// A tmux server of the test's own (tmux -L kscfg-NAME-PID) with one session "t" that runs a shell
// command on a screen of the given size. The constructor fails the test, naming tmux, when tmux is
// not installed (a missing tool never passes); the server is killed when the object dies.
struct Tmux {
  explicit Tmux(const std::string& name);
  ~Tmux();
  Tmux(const Tmux&) = delete;
  Tmux& operator=(const Tmux&) = delete;
  // Starts session "t" running `command` (through the shell) on a `columns` x `rows` screen.
  void start(const std::string& command, int columns, int rows) const;
  // tmux send-keys to session "t": `keys` as tmux words ("C-] q", "'kscfg set baud ' Tab Tab").
  void send_keys(const std::string& keys) const;
  std::string pane() const;
  // Waits until the screen holds `text` (satisfies `holds`), looking every 50 ms, at most
  // `timeout_s` seconds; returns whether it did.
  bool wait_for(const std::string& text, double timeout_s) const;
  bool wait_for(const std::function<bool(const std::string&)>& holds, double timeout_s) const;
  // Ends the server and what runs in it.
  void kill_server() const;

  std::string tmux;  // "tmux -L SOCKET "
};

}  // namespace kscfg::test
