// Shared by the catalog tests test_catalog.cpp and test_catalog_format.cpp: the built-in catalog,
// and the message of the kscfg::Error a call throws.
#pragma once
#include <catch2/catch.hpp>
#include <exception>
#include <string>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"

namespace kscfg::test {

inline const Catalog& cat() {
  static const Catalog c = Catalog::builtin();
  return c;
}

// Runs f, expects kscfg::Error with `code`; returns its message.
template <class F>
std::string error_of(F&& f, Exit code) {
  try {
    f();
  } catch (const Error& e) {
    CHECK(static_cast<int>(e.code()) == static_cast<int>(code));
    return e.what();
  } catch (const std::exception& e) {
    FAIL("expected kscfg::Error, got std::exception: " << e.what());
  }
  FAIL("expected kscfg::Error, nothing was thrown");
  return {};
}

}  // namespace kscfg::test
