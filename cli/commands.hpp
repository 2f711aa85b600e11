// Factories of the commands (one file each under commands/).
#pragma once
#include <memory>
#include <nlohmann/json.hpp>

#include "command.hpp"

namespace kscfg::cli {
// A terminal's place in the process image as info, scan and map give it (docs/json.md): {format,
// complex, inputs, outputs}, each side {offset, size} (complex) or {byte, bit, bits} (digital), or null.
nlohmann::json image_json(const TerminalImage& t);

std::unique_ptr<Command> make_info();
std::unique_ptr<Command> make_read();
std::unique_ptr<Command> make_write();
std::unique_ptr<Command> make_dump();
std::unique_ptr<Command> make_unlock();
std::unique_ptr<Command> make_lock();
std::unique_ptr<Command> make_show();
std::unique_ptr<Command> make_get();
std::unique_ptr<Command> make_set();
std::unique_ptr<Command> make_reset();
std::unique_ptr<Command> make_decode();
std::unique_ptr<Command> make_catalog();
std::unique_ptr<Command> make_backup();
std::unique_ptr<Command> make_diff();
std::unique_ptr<Command> make_apply();
std::unique_ptr<Command> make_restore();
std::unique_ptr<Command> make_map();
std::unique_ptr<Command> make_station();
std::unique_ptr<Command> make_serial();
std::unique_ptr<Command> make_data();
std::unique_ptr<Command> make_scan();
std::unique_ptr<Command> make_coupler();
std::unique_ptr<Command> make_ports();
std::unique_ptr<Command> make_serve();
std::unique_ptr<Command> make_emu();
std::unique_ptr<Command> make_emu_input();  // the `emu input` subcommand (emu_input.cpp)
std::unique_ptr<Command> make_completion();
std::unique_ptr<Command> make_manpage();
std::unique_ptr<Command> make_help();
std::unique_ptr<Command> make_complete();
}  // namespace kscfg::cli
