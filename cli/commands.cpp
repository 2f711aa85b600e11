#include "commands.hpp"

namespace kscfg::cli {

std::vector<std::unique_ptr<Command>> make_commands() {
  std::vector<std::unique_ptr<Command>> v;
  v.push_back(make_info());
  v.push_back(make_read());
  v.push_back(make_write());
  v.push_back(make_dump());
  v.push_back(make_unlock());
  v.push_back(make_lock());
  v.push_back(make_show());
  v.push_back(make_get());
  v.push_back(make_set());
  v.push_back(make_reset());
  v.push_back(make_decode());
  v.push_back(make_catalog());
  v.push_back(make_backup());
  v.push_back(make_diff());
  v.push_back(make_apply());
  v.push_back(make_restore());
  v.push_back(make_map());
  v.push_back(make_station());
  v.push_back(make_serial());
  v.push_back(make_data());
  v.push_back(make_scan());
  v.push_back(make_coupler());
  v.push_back(make_ports());
  v.push_back(make_serve());
  v.push_back(make_emu());
  v.push_back(make_completion());
  v.push_back(make_manpage());
  v.push_back(make_help());
  v.push_back(make_complete());
  return v;
}

}  // namespace kscfg::cli
