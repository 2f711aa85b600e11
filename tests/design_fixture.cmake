# The design check (tests/check_design.py) fails on a stale citation: docs/design.md with planted
# citations of what the tree does not hold (each kind of citation, and the seven functions the
# design once cited as "Held by" after they were gone) fails it, naming each; the
# same text without them passes; a source comment that cites a file that does not exist fails it;
# and the seam rules fail on a planted violation each (at the end).
# Usage: cmake -DPYTHON=python3 -DCHECK=check_design.py -DROOT=source -DWORK=dir -P this
file(REMOVE_RECURSE ${WORK})
file(READ ${ROOT}/docs/design.md design)
file(WRITE ${WORK}/clean.md "${design}")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${ROOT} --doc ${WORK}/clean.md RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the design check failed the design as it is:\n${err}")
endif()

set(planted
  "`RegisterSession::request`" "`RegisterSession::put`" "`wait_ack`" "`status_of`" "`verify_locked`"
  "`take_leftover`" "`read_retry`" "`src/session/no_such_file.cpp`" "`session/no_such.hpp`"
  "`NoSuchEngine`" "`no_such_function()`" "`proto::no_such_rule`" "`Channel::no_such_member`"
  "`KSCFG_NO_SUCH_OPTION`")
set(text "\n\n*Held by.* ")
foreach(p IN LISTS planted)
  string(APPEND text "${p}, ")
endforeach()
# A name the text places in a file that does not hold it.
string(APPEND text "`make_plan` (`src/session/channel.cpp`).\n")
file(WRITE ${WORK}/stale.md "${design}${text}")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${ROOT} --doc ${WORK}/stale.md RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0)
  message(FATAL_ERROR "the design check passed a design that cites what does not exist")
endif()
foreach(p IN LISTS planted)
  string(FIND "${err}" "${p} (" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "the design check did not name ${p}:\n${err}")
  endif()
endforeach()
if(NOT err MATCHES "`make_plan` is not in src/session/channel.cpp")
  message(FATAL_ERROR "the design check did not name a citation of the wrong file:\n${err}")
endif()

# A comment citing a file that is not there (include/kscfg/session/channel.hpp once named
# cli/main/test_hooks.cpp).
file(WRITE ${WORK}/tree/docs/design.md "# design\n")
file(WRITE ${WORK}/tree/include/kscfg/session/a.hpp "// Set by cli/main/test_hooks.cpp.\nint a;\n")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${WORK}/tree RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "include/kscfg/session/a.hpp:1: the comment cites cli/main/test_hooks.cpp")
  message(FATAL_ERROR "the design check passed a comment that cites a file that does not exist:\n${err}")
endif()
file(WRITE ${WORK}/tree/cli/main/test_hooks.cpp "int b;\n")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${WORK}/tree RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the design check failed a comment that cites a file that exists:\n${err}")
endif()

# The seam rules (check_seams): a class of include/ or src/ that derives publicly from a seam the
# architecture page lists must be in that seam's table, and a count the page states ("its two
# links") must be the number of such classes. Test doubles (tests/) and private bases do not count;
# a seam the page does not list (Port, before the code has one) is not checked.
set(seams ${WORK}/seams)
set(arch_head "# architecture\n\n| layer | holds |\n|---|---|\n| `link` | the `Link` seam and its two links |\n\n")
set(link_table "**`Link`** (`include/kscfg/link/link.hpp`): bytes.\n\n| class | file |\n|---|---|\n| `ALink`, `BLink` | `include/kscfg/link/a.hpp` |\n")
file(WRITE ${seams}/include/kscfg/link/link.hpp "class Link {\n public:\n  virtual ~Link();\n};\n")
file(WRITE ${seams}/include/kscfg/link/a.hpp
  "class ALink : public Link {};\nclass BLink final\n    : public Link {};\nclass PLink : Link {};  // private: no seam\n")
file(WRITE ${seams}/tests/link/fake.cpp "class TLink : public Link {};\n")
file(WRITE ${seams}/docs/architecture.md "${arch_head}${link_table}")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${seams} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the design check failed a seam table that lists every implementation:\n${err}")
endif()
# (a) an implementation the table does not list
file(WRITE ${seams}/src/link/c.cpp "class CLink : public Link {};\n")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${seams} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "`CLink` \\(src/link/c.cpp:1\\) implements the seam `Link`, which its table does not list")
  message(FATAL_ERROR "the design check passed an implementation missing from the seam table:\n${err}")
endif()
file(REMOVE ${seams}/src/link/c.cpp)
# (b) a count that disagrees with the code
string(REPLACE "its two links" "its three links" arch_three "${arch_head}")
file(WRITE ${seams}/docs/architecture.md "${arch_three}${link_table}")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${seams} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "says \"three links\" of the seam `Link`; include/ and src/ hold 2 \\(ALink, BLink\\)")
  message(FATAL_ERROR "the design check passed a count of a seam's implementations that is wrong:\n${err}")
endif()
# A new seam (Port): checked as soon as the page lists it, the same way.
file(WRITE ${seams}/include/kscfg/link/port.hpp "class Port {};\nclass ModbusPort : public Port {};\n")
file(WRITE ${seams}/docs/architecture.md "${arch_head}${link_table}")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${seams} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the design check failed a seam the page does not list:\n${err}")
endif()
file(WRITE ${seams}/docs/architecture.md "${arch_head}${link_table}
**`Port`** (`include/kscfg/link/port.hpp`): one port, 4 implementations.

| class | file |
|---|---|
| — | — |
")
execute_process(COMMAND ${PYTHON} ${CHECK} --root ${seams} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "`ModbusPort` \\(include/kscfg/link/port.hpp:2\\) implements the seam `Port`"
   OR NOT err MATCHES "says \"4 implementations\" of the seam `Port`; include/ and src/ hold 1 \\(ModbusPort\\)")
  message(FATAL_ERROR "the design check passed a Port seam table without its implementation:\n${err}")
endif()
