# The package changelog's entry lines fit 80 columns (lintian's debian-changelog-line-too-long,
# which CI step 30-deb turns into a failure: caught here, in the suite, before CI).
#   cmake -DFILE=packaging/changelog -P tests/check_changelog.cmake
file(STRINGS "${FILE}" lines)  # (drops empty lines: the line itself is named, not its number)
if(NOT lines)
  message(FATAL_ERROR "${FILE}: empty or missing")
endif()
foreach(line IN LISTS lines)
  # Entry lines start with two spaces; the trailer (" -- name <mail>  date") is not an entry.
  if(line MATCHES "^  ")
    string(LENGTH "${line}" len)
    if(len GREATER 80)
      message(SEND_ERROR "${FILE}: a line of ${len} columns (at most 80): ${line}")
    endif()
  endif()
endforeach()
