# The test-name check (tests/check_test_names.cmake) fails on what it is there to refuse: a stand-in
# for kscfg_tests lists test cases and tags, and a small tree holds test files. A clean list and tree
# pass; a test case name with ';', a test case name or a tag that says "issue", and a test file
# named after one each fail the check, naming what they planted.
# Usage: cmake -DCHECK=check_test_names.cmake -DWORK=dir -P this file
file(REMOVE_RECURSE ${WORK})

# Writes the stand-in: `tests --list-test-names-only` prints NAMES, `tests --list-tags` prints TAGS.
function(stand_in names tags)
  file(WRITE ${WORK}/names.txt "${names}")
  file(WRITE ${WORK}/tags.txt "${tags}")
  file(WRITE ${WORK}/tests.sh
       "#!/bin/sh\ncase \"$1\" in\n  --list-test-names-only) cat '${WORK}/names.txt' ;;\n"
       "  --list-tags) cat '${WORK}/tags.txt' ;;\n  *) exit 2 ;;\nesac\n")
  file(CHMOD ${WORK}/tests.sh PERMISSIONS OWNER_READ OWNER_WRITE OWNER_EXECUTE)
endfunction()

# Runs the check; EXPECT is "pass" or the text its failure must hold.
function(expect what expect)
  execute_process(COMMAND ${CMAKE_COMMAND} -DEXE=${WORK}/tests.sh -DROOT=${WORK}/tree -P ${CHECK}
                  RESULT_VARIABLE rc ERROR_VARIABLE err)
  if(expect STREQUAL "pass")
    if(NOT rc EQUAL 0)
      message(FATAL_ERROR "the test-name check failed ${what}:\n${err}")
    endif()
  elseif(rc EQUAL 0)
    message(FATAL_ERROR "the test-name check passed ${what}")
  else()
    string(FIND "${err}" "${expect}" at)
    if(at EQUAL -1)
      message(FATAL_ERROR "the test-name check failed ${what} without naming '${expect}':\n${err}")
    endif()
  endif()
endfunction()

set(clean_names "a set that changes nothing keeps the process data\nemu restart power-cycles the coupler\n")
set(clean_tags "All available tags:\n   2  [emu]\n   1  [set]\n2 tags\n")
file(WRITE ${WORK}/tree/tests/cli/test_emu_restart_cli.cpp "// emu restart\n")
stand_in("${clean_names}" "${clean_tags}")
expect("clean names, tags and files" "pass")

stand_in("${clean_names}a name; with a semicolon\n" "${clean_tags}")
expect("a name with ';'" "a name<SEMICOLON> with a semicolon")

stand_in("${clean_names}Issue 36 item 4: emu restart\n" "${clean_tags}")
expect("a test case named by a tracker entry" "test case: Issue 36 item 4: emu restart")

stand_in("${clean_names}" "All available tags:\n   2  [emu]\n   1  [issue23]\n2 tags\n")
expect("a tag named by a tracker entry" "tag: 1  [issue23]")

stand_in("${clean_names}" "${clean_tags}")
file(WRITE ${WORK}/tree/tests/cli/test_issue36_emu.cpp "// emu restart\n")
expect("a test file named by a tracker entry" "file: tests/cli/test_issue36_emu.cpp")
file(REMOVE ${WORK}/tree/tests/cli/test_issue36_emu.cpp)
expect("the tree once the file is gone" "pass")
