// kscfg serial line: the far end of an emulated serial terminal's line (loopback, echo, none, a
// pseudo-terminal; a UART of its own with --baud/--frame), shown or set.
#include <fmt/format.h>

#include <iostream>
#include <memory>
#include <optional>

#include "../command.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/serial_port.hpp"
#include "serial_util.hpp"

namespace kscfg::cli {

namespace {

class SerialLine : public Command {
 public:
  std::string name() const override { return "line"; }
  std::string brief() const override { return "Emulator: show or set the far end of a serial terminal's line"; }
  std::string man() const override {
    return "Emulator only. Shows the line of the selected serial terminal (baud rate and frame from R32/R33, "
           "far end) or sets its far end: \\fBloopback\\fR (TxD bridged to RxD, the default, as the KL6xx1-mode "
           "seed wires its example), \\fBecho\\fR (a device that sends back every character it receives), "
           "\\fBnone\\fR (an open line: bytes leave, nothing answers), \\fBpty\\fR or "
           "\\fBpty:\\fR\\fILINK\\fR (a pseudo-terminal, so that a program such as picocom or a modem simulator "
           "sits behind the emulated terminal; \\fILINK\\fR becomes a symlink to its device). The pseudo-terminal "
           "exists while a kscfg process runs the emulator (\\fBkscfg serve\\fR, \\fBserial term\\fR). The line "
           "moves bytes at the configured rate in emulated time: one K\\-bus cycle, one exchange of the emulator "
           "link, is 1 ms.\n"
           ".IP\n"
           "\\fB\\-\\-baud\\fR \\fIN\\fR and \\fB\\-\\-frame\\fR \\fIDPS\\fR (e.g. 8E1, 7O2) give the far "
           "end's device a UART of its own (echo, pty; a loopback bridge has none); \\fB\\-\\-match\\fR makes it "
           "follow the terminal's R32/R33 again. When the two differ, both directions of the line run bit by "
           "bit, and the terminal's receiver sees what a real one sees: a stop bit sampled low (framing error, "
           "R6 bit 2), a parity bit that does not match (parity error, R6 bit 1), or a wrong character without "
           "an error. A character with an error is lost (seed KL6001 \\(lqError handling\\(rq). \\fBserial "
           "status\\fR shows R6; \\fBserial init\\fR clears it. \\fB\\-\\-send\\fR \\fIDATA\\fR makes the far "
           "end send \\fIDATA\\fR (text with the escapes of \\fBserial send\\fR) in its frame, in emulated time "
           "as the next commands run the K\\-bus.";
  }
  std::vector<std::string> examples() const override {
    return {"serial line",
            "serial line none",
            "-t 3 serial line pty:/tmp/kl6031",
            "serial line echo --baud 9600 --frame 8E1",
            "serial line none --frame 8E1 --send 'AC'",
            "serial line --match"};
  }
  std::vector<std::string> completions() const override { return {"loopback", "echo", "none", "pty"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FAR_END", far_, "loopback, echo, none, pty or pty:LINK")->option_text("FAR_END");
    sub.add_option("--baud", baud_, "The far end's baud rate (its own UART)")->option_text("N");
    sub.add_option("--frame", frame_, "The far end's data bits, parity and stop bits, e.g. 8E1")->option_text("DPS");
    sub.add_flag("--match", match_, "The far end follows the terminal's baud rate and frame again");
    sub.add_option("--send", send_, "The far end sends DATA (text with escapes) towards the terminal")
        ->option_text("DATA");
  }
  int run(Context& ctx) override {
    EmulatedStation* emu = ctx.port().emulated();
    if (!emu)
      throw Error(Exit::usage,
                  fmt::format("'kscfg serial line' works on the emulator; the port is '{}'", ctx.options().port),
                  "use --port emu or emu:PATH");
    if (match_ && (!baud_.empty() || !frame_.empty()))
      throw Error(Exit::usage, "give either --match or --baud/--frame, not both");
    unsigned pos = serial_position(ctx);
    unsigned ch = ctx.options().channel - 1;
    const TerminalImage& t = serial_terminal(ctx.resolver().layout(), pos, ch);
    ChannelModel& m = emu->channel(pos, ch);
    SerialModel* ser = m.serial();
    if (!ser) throw Error(Exit::internal, "emulated serial terminal without a serial model");
    LineSettings ls = line_settings(*t.type, m.registers());
    std::optional<LineSettings> frame = ser->far_frame();
    if (!baud_.empty() || !frame_.empty()) {
      LineSettings base = frame.value_or(ls);
      frame = parse_line_settings(
          baud_.empty() ? std::to_string(base.baud) : baud_,
          frame_.empty() ? fmt::format("{}{}{}", base.data_bits, base.parity, base.stop_bits) : frame_);
    }
    if (match_) frame.reset();
    // A new far end first when it goes with a frame (loopback has none), the frame first when it goes.
    if (!frame) ser->set_far_frame(frame);
    if (!far_.empty()) ser->set_far_end(far_);
    if (frame) ser->set_far_frame(frame);
    if (!send_.empty()) {
      auto bytes = parse_serial_data(send_, false);
      ser->far_send(bytes);
    }
    std::string far_line = frame ? frame->describe() : "the terminal's";
    bool differs = frame && !same_frame(*frame, ls);
    if (ctx.json()) {
      nlohmann::json far_frame = nullptr;
      if (frame)
        far_frame = {{"baud", frame->baud},
                     {"frame", fmt::format("{}{}{}", frame->data_bits, frame->parity, frame->stop_bits)}};
      print_json({{"position", pos},
                  {"channel", ctx.options().channel},
                  {"type", t.type->type},
                  {"baud", ls.baud},
                  {"frame", fmt::format("{}{}{}", ls.data_bits, ls.parity, ls.stop_bits)},
                  {"far_end", ser->far_end()},
                  {"bytes_per_second", ls.bytes_per_second()},
                  {"tx_fifo", ser->tx_count()},
                  {"rx_fifo", ser->rx_count()},
                  {"r6", ser->diagnostics()},
                  {"far_frame", far_frame},
                  {"frames_differ", differs}});
    } else {
      std::cout << fmt::format("terminal {} ({}): {}, at most {:.0f} bytes/s; far end {} at {}\n", pos, t.type->type,
                               ls.describe(), ls.bytes_per_second(), ser->far_end(), far_line);
      if (differs)
        std::cout << "the frames differ: the terminal will see parity or framing errors (R6) or wrong bytes\n";
      std::cout << fmt::format("send FIFO {}/{} bytes, receive FIFO {}/{} bytes, R6 {} ({})\n", ser->tx_count(),
                               t.type->fifo_tx, ser->rx_count(), t.type->fifo_rx, hex4(ser->diagnostics()),
                               diag_text(ser->diagnostics()));
    }
    return 0;
  }

 private:
  std::string far_, baud_, frame_, send_;
  bool match_ = false;
};

}  // namespace

std::unique_ptr<Command> make_serial_line() { return std::make_unique<SerialLine>(); }

}  // namespace kscfg::cli
