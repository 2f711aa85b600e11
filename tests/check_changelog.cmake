# The package changelog's entry lines fit 80 columns (lintian's debian-changelog-line-too-long,
# which CI step 30-deb turns into a failure: caught here, in the suite, before CI).
#   cmake -DFILE=packaging/changelog -P tests/check_changelog.cmake
file(STRINGS "${FILE}" lines)
set(bad 0)
set(n 0)
foreach(line IN LISTS lines)
  math(EXPR n "${n} + 1")
  # Entry lines start with two spaces; the trailer (" -- name <mail>  date") is not an entry.
  if(line MATCHES "^  " )
    string(LENGTH "${line}" len)
    if(len GREATER 80)
      message(SEND_ERROR "${FILE}:${n}: ${len} columns (at most 80): ${line}")
      set(bad 1)
    endif()
  endif()
endforeach()
if(n EQUAL 0)
  message(FATAL_ERROR "${FILE}: empty or missing")
endif()
