// The scan cache: what a scan learned, kept between runs; a broken or foreign entry is no entry.
#include <sys/stat.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>

#include "kscfg/discovery/scan.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/link/port_uri.hpp"
#include "support.hpp"

using namespace kscfg;

namespace {

ScanResult sample(const Catalog& cat) {
  ScanHead h;
  h.ident = "BK9000";
  h.ident_read = true;
  h.lengths = {384, 384, 4, 4};
  ScanResult r = begin_scan(h, "test", std::nullopt);
  std::vector<std::map<unsigned, std::uint16_t>> kl6001(1);
  kl6001[0] = {{8, 6001}, {34, 0x0001}, {35, 5}};  // standard format, 5 data bytes
  add_scanned_terminal(r, cat.get("KL6001"), 6001, kl6001);
  std::vector<std::map<unsigned, std::uint16_t>> kl5101(1);
  kl5101[0] = {{8, 5101}};
  add_scanned_terminal(r, cat.get("KL5101"), 5101, kl5101);
  r.layout = scan_layout(r, cat);
  return r;
}

ModbusTarget target(const std::string& uri) { return modbus_target(parse_port_uri(uri), uri); }

}  // namespace

TEST_CASE("scan cache: stored and loaded again, per port and unit", "[scan]") {
  const Catalog& cat = Catalog::standard();
  test::TempDir dir;
  ScanCache a(dir.path, target("tcp://127.0.0.1:5020"));
  ScanCache b(dir.path, target("tcp://127.0.0.1:5020?unit=2"));
  CHECK(a.path() != b.path());
  CHECK_FALSE(a.load(cat));
  CachedScan c;
  c.scan = sample(cat);
  c.ack_wait[1] = std::chrono::microseconds(2100);
  REQUIRE(a.lock(1, nullptr));
  REQUIRE(a.store(c));
  a.unlock();
  auto back = a.load(cat);
  REQUIRE(back);
  REQUIRE(back->scan);
  CHECK(back->scan->from_cache);
  CHECK(back->scan->ident == "BK9000");
  CHECK(back->scan->complex_out_bits == 384);
  CHECK(back->scan->digital_in_bits == 4);
  REQUIRE(back->scan->spec.terminals.size() == 2);
  CHECK(back->scan->spec.terminals[0].type == "KL6001");
  CHECK(back->scan->r8 == std::vector<unsigned>{6001, 5101});
  CHECK(back->scan->regs[0][0].at(35) == 5);
  CHECK(back->ack_wait.at(1) == std::chrono::microseconds(2100));
  // The layout follows the registers as scanned: KL6001 standard format with 5 data bytes.
  const auto& t1 = back->scan->layout.terminal(1);
  CHECK(t1.in_size == 6);
  CHECK(back->scan->layout.terminal(2).in_offset == 6);
  CHECK_FALSE(b.load(cat));
}

TEST_CASE("scan cache: a broken, foreign or unknown entry is no entry", "[scan]") {
  const Catalog& cat = Catalog::standard();
  test::TempDir dir;
  ScanCache a(dir.path, target("tcp://10.0.0.5"));
  CachedScan c;
  c.scan = sample(cat);
  REQUIRE(a.store(c));
  std::string good = test::read_text(a.path());
  for (std::string bad : {std::string("{"), std::string("[]"), std::string(""), [&] {
                            auto s = good;
                            s.replace(s.find("\"format\": 1"), 11, "\"format\": 9");
                            return s;
                          }()}) {
    test::write_text(a.path(), bad);
    INFO(bad.substr(0, 40));
    CHECK_FALSE(a.load(cat));
  }
  // A type this catalog does not know: the latencies stay useful, the scan does not.
  std::string unknown = good;
  unknown.replace(unknown.find("KL5101"), 6, "KL5199");
  test::write_text(a.path(), unknown);
  auto l = a.load(cat);
  REQUIRE(l);
  CHECK_FALSE(l->scan);
  a.remove();
  CHECK_FALSE(std::filesystem::exists(a.path()));
}

TEST_CASE("scan cache: the lock is bounded", "[scan]") {
  test::TempDir dir;
  ScanCache a(dir.path, target("tcp://10.0.0.6")), b(dir.path, target("tcp://10.0.0.6"));
  REQUIRE(a.lock(1, nullptr));
  auto t0 = std::chrono::steady_clock::now();
  CHECK_FALSE(b.lock(0.2, nullptr));
  CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5));
  a.unlock();
  CHECK(b.lock(1, nullptr));
}

TEST_CASE(
    "scan cache: a link where the entry goes is replaced, never written through, a lock path that is no file "
    "is refused",
    "[scan]") {
  namespace fs = std::filesystem;
  const Catalog& cat = Catalog::standard();
  test::TempDir dir;
  ScanCache a(dir.path, target("tcp://10.0.0.7"));
  fs::create_directories(fs::path(a.path()).parent_path());
  std::string victim = dir.file("victim");
  test::write_text(victim, "keep me\n");
  fs::create_symlink(victim, a.path());
  std::vector<std::string> notes;
  CHECK_FALSE(a.load(cat, [&](const std::string& s) { notes.push_back(s); }));  // a link is no entry
  REQUIRE(notes.size() == 1);
  CHECK_THAT(notes[0], Catch::Contains("is a symbolic link"));
  CachedScan c;
  c.scan = sample(cat);
  REQUIRE(a.store(c));
  CHECK(test::read_text(victim) == "keep me\n");
  CHECK_FALSE(fs::is_symlink(a.path()));
  CHECK(a.load(cat));
  // A killed writer's temporary beside the entry is removed by the next store.
  std::string stale = a.path() + ".tmp.999999999";
  test::write_text(stale, "{");
  REQUIRE(a.store(c));
  CHECK_FALSE(fs::exists(stale));
  // A FIFO at the lock path never blocks the open; a link there is refused (not followed).
  ScanCache b(dir.path, target("tcp://10.0.0.8"));
  REQUIRE(::mkfifo((b.path() + ".lock").c_str(), 0644) == 0);
  auto t0 = std::chrono::steady_clock::now();
  (void)b.lock(0.2, nullptr);
  CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5));
  b.unlock();
  ScanCache d(dir.path, target("tcp://10.0.0.9"));
  fs::create_symlink(victim, d.path() + ".lock");
  CHECK_FALSE(d.lock(0.2, nullptr));
  CHECK(test::read_text(victim) == "keep me\n");
}
