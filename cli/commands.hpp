// Factories of the commands (one file each under commands/).
#pragma once
#include <memory>

#include "command.hpp"

namespace kscfg::cli {
std::unique_ptr<Command> make_info();
std::unique_ptr<Command> make_read();
std::unique_ptr<Command> make_write();
std::unique_ptr<Command> make_dump();
std::unique_ptr<Command> make_unlock();
std::unique_ptr<Command> make_lock();
std::unique_ptr<Command> make_emu();
std::unique_ptr<Command> make_completion();
std::unique_ptr<Command> make_manpage();
}  // namespace kscfg::cli
