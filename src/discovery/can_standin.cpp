// TEMPORARY stand-in (H3, issue 37): coupler_lock_path(CanTarget), which H1's branch defines in
// open.cpp. The lead drops this file.
#include <filesystem>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/discovery/open.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"

namespace kscfg {

std::string coupler_lock_path(const CanTarget& t) {
  return (std::filesystem::path(lock_dir()) / (coupler_key(t) + ".lock")).string();
}

}  // namespace kscfg
