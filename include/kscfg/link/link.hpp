// The one seam: a Link moves bytes of a coupler's process image. It knows nothing of registers.
#pragma once
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>

#include "kscfg/base/error.hpp"

namespace kscfg {

// One terminal channel's part of an image exchange (Link::transfer): output bytes to write and
// input bytes to read; either may be empty.
struct ImageTransfer {
  std::size_t out_offset = 0;
  std::span<const std::uint8_t> out;
  std::size_t in_offset = 0;
  std::span<std::uint8_t> in;
  // A read the link may carry where it costs nothing (a terminal's status looked at while it waits
  // for an answer, with another terminal's exchange): never an exchange of its own. The link sets
  // *carried when it read it; a peek has no out bytes.
  bool peek = false;
  bool* carried = nullptr;
};

class Link {
 public:
  virtual ~Link() = default;
  virtual std::string describe() const = 0;

  // Input image bytes [offset, offset + dst.size()).
  virtual void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) = 0;
  // Output image bytes as the coupler holds them now.
  virtual void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) = 0;
  // Writes output bytes; bytes outside the span are left as they are.
  virtual void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) = 0;

  // Whether a master other than this process may write the coupler's outputs (a Modbus coupler: a
  // kscfg on another computer, KS2000). The emulator's state file is locked: never.
  virtual bool other_masters_possible() const { return false; }

  // How long to leave between two polls of the input image, the `poll_number`-th since a wait
  // began (the caller sleeps it, bounded by its timeout): the link's pace, a fact of the transport
  // (the emulator runs a K-bus cycle on every read and needs none; a Modbus coupler the client's
  // poll interval, longer once a terminal takes long).
  virtual std::chrono::microseconds poll_gap(unsigned poll_number) const {
    (void)poll_number;
    return std::chrono::microseconds(0);
  }

  // On a link that pipelines, the reads of a transfer() see the image as it was before the K-bus
  // carried its writes: they show the answer to the previous request, so register reads can overlap
  // (Modbus FC23, ADS requests in flight together).
  virtual bool pipelines() const { return false; }

  // Writes the output bytes of every transfer, then reads the input bytes of every transfer, in as
  // few exchanges as the link allows: the station engine advances the handshakes of many terminals
  // at once with it. A Modbus link puts them in one FC23 when they fit its limits (121 registers
  // written, 125 read), bytes between the spans written keeping what the coupler holds; on a link
  // that pipelines, the reads see the image as it was before the terminals saw the writes.
  // Default: each output span written, then one read covering every input span.
  virtual void transfer(std::span<const ImageTransfer> t);

  // A terminal did not acknowledge: the link may know a cause beyond the terminal (a coupler
  // whose watchdog switched the outputs off). Returns the error to report instead, if any.
  virtual std::optional<Error> explain_no_ack() { return std::nullopt; }

  // A link proven dead (Modbus: two requests in a row got no answer): every later request fails
  // before anything goes out. The session journal notes no control byte then, since none reaches a
  // terminal: noted, the bytes of a rollback tried against it pushed the one the terminal holds out
  // of the last ones a journal keeps (docs/safety.md section 2).
  virtual bool proven_dead() const { return false; }

  // A poll of the input image costs a network round trip rather than line time (Modbus TCP): the
  // handshake paces its probes by it (ADS and a serial line keep their plan).
  virtual bool poll_is_round_trip() const { return false; }

  // Link exchanges so far (one request/response on a real link, also those others sent over its
  // connection, such as a scan's identification reads; one image access on the emulator).
  virtual std::size_t exchanges() const { return exchanges_; }

 protected:
  std::size_t exchanges_ = 0;
};

}  // namespace kscfg
