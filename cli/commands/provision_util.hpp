// Shared by diff/apply/restore: printing a plan.
#pragma once
#include <nlohmann/json.hpp>
#include <string>

#include "kscfg/provision.hpp"

namespace kscfg::cli {
nlohmann::json plan_json(const Plan& plan);
std::string plan_text(const Plan& plan);
// apply and restore: plan, back up, write, roll back on failure. Returns the exit code.
int run_apply(class Context& ctx, const std::string& file, bool dry_run, const std::string& backup);
}  // namespace kscfg::cli
