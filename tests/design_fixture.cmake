# The design check (tests/check_design.py) fails on a stale citation: docs/design.md with planted
# citations of what the tree does not hold (each kind of citation, and the seven functions the
# design once cited as "Held by" after they were gone) fails it, naming each; the
# same text without them passes; and a source comment that cites a file that does not exist fails
# it too. Usage: cmake -DPYTHON=python3 -DCHECK=check_design.py -DROOT=source -DWORK=dir -P this
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
