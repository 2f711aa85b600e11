# A test that needs a tool fails when the tool is missing, never passes:
# runs EXE ARGS with an empty PATH and expects a failure that names TOOL.
file(MAKE_DIRECTORY ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} -E env PATH=${WORK} ${EXE} ${ARGS}
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc EQUAL 0)
  message(FATAL_ERROR "'${ARGS}' passed without ${TOOL} on PATH:\n${out}${err}")
endif()
if(NOT "${out}${err}" MATCHES "${TOOL} is not installed")
  message(FATAL_ERROR "'${ARGS}' failed without naming the missing ${TOOL} (exit ${rc}):\n${out}${err}")
endif()
message(STATUS "without ${TOOL}: failed, naming it")
