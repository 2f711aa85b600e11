// The station-size sweep of bench_modbus (station_sweep.cpp).
#pragma once
#include <vector>

#include "harness.hpp"

namespace bench {

// Stations of 1..16 KL6001 behind kscfg serve and the pymodbus peer, TCP and RTU: backup, apply of
// one parameter per terminal, cold info; rows with the ratios to the 1-terminal station.
void station_sweep(const Options& o, std::vector<Row>& rows);

// Request counts: cold info at 8, 12 and 16 terminals through serve against the walk's
// floor; warm info and read R8 against --station, 20 runs each, quiet and loaded (`--only counts`).
void request_counts(const Options& o, std::vector<Row>& rows);

}  // namespace bench
