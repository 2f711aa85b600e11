// kscfg apply FILE: make the station match a station file; idempotent, verified, rolled back on failure.
#include <fmt/format.h>

#include <cstdlib>
#include <filesystem>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../progress.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/verdict.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

namespace {}  // namespace

// How many automatic backups of a port to keep: --keep-backups, else KSCFG_BACKUP_KEEP, else 20.
unsigned backup_keep(std::optional<unsigned> keep) {
  if (keep) return *keep;
  if (const char* e = std::getenv("KSCFG_BACKUP_KEEP"); e && *e)
    return static_cast<unsigned>(parse_uint(e, 1'000'000, "KSCFG_BACKUP_KEEP"));
  return 20;
}

BackupInfo backup_info(Context& ctx) {
  BackupInfo info;
  info.coupler = ctx.resolver().layout().coupler;
  nlohmann::json lj = ctx.link_json();
  info.port = lj["port"].get<std::string>();
  if (!lj["unit"].is_null()) info.unit = lj["unit"].get<unsigned>();
  info.identification = ctx.port().identification();
  std::error_code ec;
  if (!ctx.options().station.empty()) info.station = std::filesystem::absolute(ctx.options().station, ec).string();
  info.version = KSCFG_VERSION;
  return info;
}

UndoSaver::UndoSaver(Context& ctx, std::string kind)
    : ctx_(ctx), kind_(std::move(kind)), info_(backup_info(ctx)), layout_(ctx.resolver().layout()) {
  info_.automatic = true;
  info_.keep = backup_keep(std::nullopt);
}

std::string UndoSaver::operator()(const SessionJournal::Change& change) {
  path_ = default_backup_path(info_.port, kind_);
  SavedUndo saved = save_undo_file(layout_, info_.coupler, change, path_, info_, kind_);
  undo_ = saved.undo;
  if (ctx_.options().verbose)
    for (const auto& old : saved.rotated) ctx_.trace("removed old backup " + old);
  return saved.undo;
}

void UndoSaver::say() const {
  if (path_.empty()) return;
  std::cerr << "kscfg: backup of the touched registers: " << path_ << '\n';
  std::cerr << "kscfg: undo with: " << undo_ << '\n';
}

int run_apply(Context& ctx, const std::string& file, bool dry_run, const std::string& backup, bool force,
              const std::string& what, std::optional<unsigned> keep, bool detailed) {
  if (backup == "-")
    throw Error(Exit::usage, "--backup - would mix the backup with the plan on stdout", "give --backup a file name");
  StationSpec want = load_station_arg(file, ctx.catalog());
  // A partial file (position = N): the station's other terminals are left alone.
  if (want.partial()) want = expand_partial(want, ctx.resolver().layout());
  const StationLayout& layout = ctx.resolver().layout_for(want);
  Plan plan;
  {
    ProgressBar bar(ctx, what + ": reading", 0);  // on a terminal only (progress.hpp)
    plan =
        make_plan(ctx.resolver().library_engine(), layout, want, ctx.catalog(), ctx.session_options(), bar.callback());
  }
  // The one verdict on this change (session/verdict.hpp), the same for --dry-run (and so for the
  // Ansible module's check mode), diff and station check: refused with status 5 before anything is
  // written, unless --force.
  Verdict verdict;
  if (plan.changes())
    verdict = enforce_verdict(&ctx.resolver().library_engine(), layout, ctx.catalog(), ctx.session_options(),
                              planned_writes(plan, &want, &ctx.catalog()), force);
  if (dry_run || !plan.changes()) {
    if (ctx.json()) {
      print_json(provision_json(ctx, plan, dry_run, ""));
    } else {
      std::cout << (plan.changes() ? plan_text(plan) : "no change needed\n");
    }
    return dry_run && plan.changes() ? static_cast<int>(Exit::differences) : 0;
  }
  BackupInfo info = backup_info(ctx);
  info.coupler = layout.coupler;
  std::error_code ec;
  info.applied = file == "-" ? std::string("- (stdin)") : std::filesystem::absolute(file, ec).string();
  info.automatic = backup.empty();
  info.keep = backup_keep(keep);
  std::string path = backup.empty() ? default_apply_backup_path(info.port) : backup;
  ApplyResult r;
  {
    ProgressBar bar(ctx, what + ": writing", 0);
    r = apply_plan(ctx.resolver().library_engine(), layout, plan, ctx.session_options(), layout.coupler, path,
                   bar.callback(), info);
  }
  std::cerr << "kscfg: backup of the touched registers: " << r.backup_path << '\n';
  std::cerr << "kscfg: undo with: " << r.undo << '\n';
  if (std::string n = next_start_note(verdict.lockout); !n.empty()) std::cerr << "kscfg: note: " << n << '\n';
  if (ctx.options().verbose)
    for (const auto& old : r.rotated) ctx.trace("removed old backup " + old);
  if (ctx.json()) {
    nlohmann::json j = provision_json(ctx, plan, false, r.backup_path);
    j["undo"] = r.undo;
    print_json(j);
  } else {
    std::cout << plan_text(plan);
  }
  // A change that worked is a success (`kscfg apply f.toml && ...`, `set -e`); the output says it
  // changed, and --detailed-exitcode tells it by the status as well.
  return detailed ? static_cast<int>(Exit::changed) : 0;
}

namespace {

class Apply : public ApplyCommand {
 public:
  std::string name() const override { return "apply"; }
  std::string brief() const override { return "Make the station match a station file"; }
  std::string man() const override {
    return "Makes the station match \\fIFILE\\fR. First it checks that every terminal type and position "
           "matches and refuses, naming the mismatch, before anything is written. Then it reads what the "
           "file configures and writes only what differs, each terminal as one verified change. Before the "
           "first write it saves the touched registers' current values to a station file (path on stderr, "
           "\\fB\\-\\-backup\\fR to choose it) that \\fBkscfg restore\\fR puts back; it records the port, the "
           "Modbus unit, the coupler and its identification, the applied file, the time and kscfg's version, "
           "and ends with the command that undoes the change (\\fIkscfg \\-\\-port PORT restore FILE\\fR, also "
           "printed on stderr and in \\fB\\-\\-json\\fR as \\fBbackup\\fR and \\fBundo\\fR). Automatic backups "
           "are kept per port under \\fI$XDG_STATE_HOME/kscfg/backups/PORT/\\fR; the newest 20 are kept "
           "(\\fB\\-\\-keep\\-backups\\fR \\fIN\\fR or \\fBKSCFG_BACKUP_KEEP\\fR; 0 keeps all). If any write fails, "
           "every "
           "register this run wrote is restored and the exit status says why. Running apply twice changes "
           "nothing the second time. Exit status: 0 success (the output says whether anything changed: "
           "\\fBno change needed\\fR, or the changes; \\fBchanged\\fR in \\fB\\-\\-json\\fR), other: failure "
           "(nothing left half-written); with \\fB\\-\\-detailed\\-exitcode\\fR (as Terraform's), 0 nothing "
           "to change, 10 changed. \\fB\\-\\-dry\\-run\\fR prints the plan and exits like \\fBdiff\\fR. "
           "A plan with a value the catalog does not document for its register (a raw \\fBR32 = 0x00FF\\fR on "
           "a KL6001), with settings that go together left apart (KL6031 \\fBimage\\-size\\fR and "
           "\\fBextended\\-image\\fR) or that would leave a terminal without its register window at the "
           "coupler's next start (see \\fBwrite\\fR) is refused with status 5 before anything is written, "
           "with \\fB\\-\\-dry\\-run\\fR too (so Ansible's check mode fails as the real run would); "
           "\\fBdiff\\fR, \\fBset\\fR, \\fBwrite\\fR and \\fBstation check\\fR refuse the same change "
           "with the same message. \\fB\\-\\-force\\fR applies it anyway (with \\fB\\-\\-dry\\-run\\fR: "
           "shows the plan).";
  }
  std::vector<std::string> examples() const override {
    return {"apply line3.toml", "apply --dry-run line3.toml", "--port tcp://10.0.0.5 --json apply line3.toml",
            "apply --detailed-exitcode line3.toml"};
  }
};

}  // namespace

std::unique_ptr<Command> make_apply() { return std::make_unique<Apply>(); }

}  // namespace kscfg::cli
