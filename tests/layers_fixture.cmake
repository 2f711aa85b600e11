# Builds a small tree in which the link layer includes the session layer, runs the layer check on
# it and fails unless the check fails naming that include; then checks that the same tree without
# the upward include passes.
file(REMOVE_RECURSE ${WORK})
file(WRITE ${WORK}/include/kscfg/session/session.hpp "#pragma once\n")
file(WRITE ${WORK}/include/kscfg/base/error.hpp "#pragma once\n")
file(WRITE ${WORK}/src/link/bad.cpp "#include \"kscfg/base/error.hpp\"\n#include \"kscfg/session/session.hpp\"\n")
execute_process(COMMAND ${CMAKE_COMMAND} -DROOT=${WORK} -P ${CHECK} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0)
  message(FATAL_ERROR "the layer check passed a tree in which link includes session")
endif()
if(NOT err MATCHES "src/link/bad.cpp: layer 'link' includes 'session'")
  message(FATAL_ERROR "the layer check failed without naming the upward include:\n${err}")
endif()
file(WRITE ${WORK}/src/link/bad.cpp "#include \"kscfg/base/error.hpp\"\n")
execute_process(COMMAND ${CMAKE_COMMAND} -DROOT=${WORK} -P ${CHECK} RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the layer check failed a tree without upward includes:\n${err}")
endif()
