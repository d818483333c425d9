# Fails when a GoogleTest suite matches no area filter: such a suite would otherwise run under no name at all.
# Usage: cmake -DTESTS=<sfgs_tests> -DASSIGNED=<filter:filter...> -P check_suites_have_areas.cmake
execute_process(COMMAND ${TESTS} --gtest_list_tests "--gtest_filter=*-${ASSIGNED}"
                OUTPUT_VARIABLE listed RESULT_VARIABLE status)
if(NOT status EQUAL 0)
  message(FATAL_ERROR "${TESTS} --gtest_list_tests exited with ${status}")
endif()
string(STRIP "${listed}" listed)
if(NOT listed STREQUAL "")
  message(FATAL_ERROR "These suites match no area in tests/CMakeLists.txt (SFGS_TEST_AREAS); add them to one:\n${listed}")
endif()
message(STATUS "Every GoogleTest suite belongs to an area.")
