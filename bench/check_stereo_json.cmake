# Runs `craftscan-bench stereo` with sgbm on one scene and checks its JSON:
# structure, and sgbm's bad-1 nonocc on Tsukuba within a loose sanity band.
#   cmake -DBENCH=... -DSCENE=... -DJSON=... -P check_stereo_json.cmake
file(REMOVE "${JSON}")
execute_process(
  COMMAND "${BENCH}" stereo --scene "${SCENE}" --matcher sgbm --repeat 1 --json "${JSON}"
  RESULT_VARIABLE code)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "craftscan-bench exited with ${code}")
endif()
file(READ "${JSON}" text)
string(JSON threads GET "${text}" threads)
string(JSON n LENGTH "${text}" scenes)
string(JSON name GET "${text}" scenes 0 name)
string(JSON width GET "${text}" scenes 0 width)
string(JSON ndisp GET "${text}" scenes 0 ndisp)
if(NOT threads EQUAL 2 OR NOT n EQUAL 1 OR NOT name STREQUAL "tsukuba_2001" OR NOT width EQUAL 384
   OR NOT ndisp EQUAL 16)
  message(FATAL_ERROR "unexpected JSON header fields:\n${text}")
endif()
foreach(key bad1_nonocc bad2_nonocc avgerr_nonocc density time_ms bad1_all bad1_disc)
  string(JSON value GET "${text}" scenes 0 results sgbm ${key})
  message("sgbm ${key} = ${value}")
endforeach()
string(JSON bad1 GET "${text}" scenes 0 results sgbm bad1_nonocc)
# SGBM on Tsukuba is typically a few to ~10 % bad-1 (holes count as bad).
if(bad1 LESS 0.5 OR bad1 GREATER 30)
  message(FATAL_ERROR "sgbm bad1_nonocc ${bad1} % outside the sanity band [0.5, 30]")
endif()
