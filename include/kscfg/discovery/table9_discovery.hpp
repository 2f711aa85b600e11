// The port's StationDiscovery over a coupler that lists its terminals in its table 9 (ADS port 100,
// CANopen 0x4500/0x4501): scan_table9 through the transport's reader (discovery/table9.hpp), check
// off, once, on first use.
#pragma once
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/discovery/table9.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

class Table9Discovery : public StationDiscovery {
 public:
  // `reader`: the transport's (ads_table9_reader, can_table9_reader); `status`: what it is doing
  // while it reads the coupler (station_discovery.hpp).
  Table9Discovery(std::unique_ptr<Table9Reader> reader, const Catalog& catalog,
                  std::function<void(const std::string&)> trace = {}, DiscoveryStatus status = {});
  const StationLayout* layout_upto(unsigned upto) override;
  const StationSpec* station() override;
  // A station file compared with the station (diff, apply, restore): the file's layout, its positions
  // with the passive terminals table 9 does not list, checked as check_described does.
  std::optional<StationLayout> match(const StationSpec& file) override;
  // The file's terminals with a number on the coupler (on port 100, a 0x4501 sub-index) against
  // table 9, in order (a complex one by its type, a digital one by its bits and direction; the file
  // names which type it is): Error(refused) naming the first difference. Then what the reader checks
  // besides (ADS: the layout against the coupler's image lengths). A coupler whose station cannot be
  // laid out (Error(usage)) leaves the file unchecked, said in the trace.
  void check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) override;

 private:
  std::unique_ptr<Table9Reader> reader_;
  const Catalog& catalog_;
  std::function<void(const std::string&)> trace_;
  DiscoveryStatus status_;
  Table9Reader::Words words_;
  std::optional<Table9Scan> found_;
  bool searched_ = false;
};

}  // namespace kscfg
