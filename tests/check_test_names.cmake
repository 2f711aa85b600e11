# CTest runs each Catch2 test case by its name; catch_discover_tests passes names as a CMake list,
# so a name with ';' is split and its ctest runs a filter that matches nothing and "passes".
# Fails when any test case name holds a ';' (usage: cmake -DEXE=kscfg_tests -P this file).
execute_process(COMMAND ${EXE} --list-test-names-only OUTPUT_VARIABLE names RESULT_VARIABLE rc)
if(NOT rc EQUAL 0 AND names STREQUAL "")
  message(FATAL_ERROR "cannot list the test names of ${EXE}")
endif()
string(REPLACE ";" "<SEMICOLON>" names "${names}")
string(REPLACE "\n" ";" lines "${names}")
set(bad "")
foreach(line IN LISTS lines)
  if(line MATCHES "<SEMICOLON>")
    string(APPEND bad "\n  ${line}")
  endif()
endforeach()
if(bad)
  message(FATAL_ERROR "test case names with ';' never run under CTest (use ','):${bad}")
endif()
