# Checks that the library's layers only include downwards (src/README.md draws the picture).
# Usage: cmake -DROOT=<source dir> -P check_layers.cmake
# Fails (FATAL_ERROR) naming every file that includes a header of a layer it may not use, every
# dynamic_cast of a link in the library or the CLI, and every global interrupt flag or cancellation
# token in the library.
# Run at configure time and as the CTest test "layers", so an upward include breaks the build.

include(${CMAKE_CURRENT_LIST_DIR}/layers.cmake)

if(NOT ROOT)
  message(FATAL_ERROR "check_layers: pass -DROOT=<source dir>")
endif()

set(violations "")
foreach(layer IN LISTS KSCFG_LAYERS)
  file(GLOB_RECURSE files ${ROOT}/src/${layer}/*.cpp ${ROOT}/src/${layer}/*.hpp
       ${ROOT}/include/kscfg/${layer}/*.hpp)
  foreach(f IN LISTS files)
    file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include[ \t]*[\"<]kscfg/")
    foreach(line IN LISTS lines)
      string(REGEX MATCH "kscfg/([a-z_]+)/" _ "${line}")
      set(target "${CMAKE_MATCH_1}")
      if(target STREQUAL "")
        # A header outside every layer folder (the flat include/kscfg/ of old): not allowed.
        file(RELATIVE_PATH rel ${ROOT} ${f})
        list(APPEND violations "${rel}: ${line} (not in a layer folder)")
      elseif(NOT target STREQUAL layer)
        list(FIND KSCFG_USES_${layer} ${target} ok)
        if(ok EQUAL -1)
          file(RELATIVE_PATH rel ${ROOT} ${f})
          list(APPEND violations "${rel}: layer '${layer}' includes '${target}': ${line}")
        endif()
      endif()
    endforeach()
  endforeach()
endforeach()

# The library never includes the CLI.
file(GLOB_RECURSE libfiles ${ROOT}/src/*.cpp ${ROOT}/src/*.hpp ${ROOT}/include/*.hpp)
foreach(f IN LISTS libfiles)
  file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include[ \t]*\"(commands|context|command|app)\\.hpp\"")
  foreach(line IN LISTS lines)
    file(RELATIVE_PATH rel ${ROOT} ${f})
    list(APPEND violations "${rel}: the library includes the CLI: ${line}")
  endforeach()
endforeach()

# Nothing downcasts a link or asks it what it is (docs/architecture.md, "Ports"): what differs by
# transport is the Port's (discovery/port.hpp), chosen once from the scheme table.
file(GLOB_RECURSE castfiles ${ROOT}/src/*.cpp ${ROOT}/src/*.hpp ${ROOT}/include/*.hpp ${ROOT}/cli/*.cpp
     ${ROOT}/cli/*.hpp)
foreach(f IN LISTS castfiles)
  file(STRINGS ${f} lines REGEX "dynamic_cast[ \t]*<[^>]*(Link|ModbusClient|ModbusRegisters|AdsClient|EmulatedStation|Port)[ \t]*[&*]")
  foreach(line IN LISTS lines)
    file(RELATIVE_PATH rel ${ROOT} ${f})
    string(STRIP "${line}" line)
    list(APPEND violations "${rel}: a downcast of a link or port (the Port answers for its transport): ${line}")
  endforeach()
  file(STRINGS ${f} lines REGEX "(modbus_registers|ads_connection|sdo_connection)[ \t]*\\(|(\\.|->)emulator[ \t]*\\(\\)")
  foreach(line IN LISTS lines)
    file(RELATIVE_PATH rel ${ROOT} ${f})
    string(STRIP "${line}" line)
    list(APPEND violations "${rel}: a link asked for a transport's capability (the Port answers for its transport): ${line}")
  endforeach()
endforeach()

# Cancellation is passed, not global (docs/engine.md section 2.3): no library file names a process-wide
# interrupt flag (the g_interrupted/g_interrupts/g_signal of old) or holds a CancelToken of its own
# at namespace scope; the CLI makes the one token and passes it to every wait.
foreach(f IN LISTS libfiles)
  file(STRINGS ${f} lines REGEX "g_interrupted|g_interrupts|g_signal|pause_interrupt|resume_interrupt")
  foreach(line IN LISTS lines)
    file(RELATIVE_PATH rel ${ROOT} ${f})
    string(STRIP "${line}" line)
    list(APPEND violations "${rel}: a global interrupt flag in the library (pass a CancelToken): ${line}")
  endforeach()
  file(STRINGS ${f} lines REGEX "^(static |extern |inline )*(const )?(kscfg::)?CancelToken[ \t]+[A-Za-z_][A-Za-z_0-9]*[ \t]*(;|\\{|=)")
  foreach(line IN LISTS lines)
    file(RELATIVE_PATH rel ${ROOT} ${f})
    string(STRIP "${line}" line)
    list(APPEND violations "${rel}: a global cancellation token in the library (the CLI owns the one token): ${line}")
  endforeach()
endforeach()

if(violations)
  list(JOIN violations "\n  " text)
  message(FATAL_ERROR "upward include(s), link downcast(s) or global cancellation, see src/README.md for the layers:\n  ${text}")
endif()
