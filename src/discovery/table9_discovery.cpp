// The port's discovery over a coupler's table 9 (discovery/table9_discovery.hpp).
#include "kscfg/discovery/table9_discovery.hpp"

#include <fmt/format.h>

#include "kscfg/discovery/match.hpp"

namespace kscfg {

Table9Discovery::Table9Discovery(std::unique_ptr<Table9Reader> reader, const Catalog& catalog,
                                 std::function<void(const std::string&)> trace, DiscoveryStatus status)
    : reader_(std::move(reader)),
      catalog_(catalog),
      trace_(std::move(trace)),
      status_(std::move(status)),
      words_(reader_->words()) {}

const StationLayout* Table9Discovery::layout_upto(unsigned) {
  if (!searched_) {
    searched_ = true;
    Table9ScanOptions so;
    so.check = false;  // table 9 and the registers that decide an image only
    so.trace = trace_;
    StatusScope status(status_, words_.reading);
    so.status = [&status](const std::string& d) { status.detail(d); };
    Table9Scan s = scan_table9(*reader_, catalog_, so);
    if (trace_)
      for (const auto& n : s.result.notes) trace_(words_.transport + ": " + n);
    found_ = std::move(s);
  }
  return found_ ? &found_->result.layout : nullptr;
}

const StationSpec* Table9Discovery::station() { return layout() ? &found_->result.spec : nullptr; }

std::optional<StationLayout> Table9Discovery::match(const StationSpec& file) {
  StationLayout L = compute_layout(file, catalog_);
  check_described(L, file, file.origin);
  return L;
}

void Table9Discovery::check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) {
  if (words_.registers_direct) L.registers_direct = true;
  const StationLayout* found = nullptr;
  try {
    found = layout();
  } catch (const Error& e) {
    if (e.code() != Exit::usage) throw;
    if (trace_)
      trace_(fmt::format("{}: {} is not checked against the coupler: {}", words_.transport, origin, e.what()));
    return;
  }
  if (!found) return;
  match_table9(L, *found, origin, words_.numbered_by);
  reader_->check_file(L, spec, *found_, catalog_, origin);
}

}  // namespace kscfg
