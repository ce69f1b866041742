# test_costs.cmake — the order ctest starts the tests in (its COST property: the largest first).
#
# ctest times every test into Testing/Temporary/CTestCostData.txt and orders later runs by those
# times; a fresh build tree (CI's clone) has none, so without COST it starts the tests in the order
# they were added, and at two at a time (scripts/test.sh) a long test started late is the last to
# finish while the other core idles. Here: the tests that run alone (RUN_SERIAL: the MPI ranks,
# the OpenMP points tests) first, while nothing else runs, then the longest first. The figures
# are seconds under ASan + UBSan (build-asan), from ctest's LastTest.log of a whole run; tests
# not named here cost 0 and start after these, in the order they were added.
set(NPG_TEST_COSTS
  # RUN_SERIAL
  mpi_train 100003
  points_fmm 100002
  points_expansions 100001
  points_visibility 100000
  # the longest, as measured
  cli_stream 542
  test_api 142
  hostile_trial2 94
  python_npg 31
  test_ooc 29
  hostile_corpus 28
  hostile_trial3 25
  radiosity_options 25
  test_full 23
  cli_interp 22
  fluids_cavity_train_workers 21
  radiosity_demo 18
  cli_simulate_burgers 15
  docs_examples 13
  test_emit_reduced 12
  fluids_cavity_smoke 12
  fluids_tunnel_step_program 8
  cli_interrupt 8
  cli_estimate 7
  cli_hardening 6
  cli_numerics 6
  fluids_cavity_reduced_step 6
  test_tune 6
  test_pca 6
  cli_data_safety 6
  cli_simulate 5)

# The COST of every test of the calling folder that NPG_TEST_COSTS names (npg_test_cache_env
# calls it at the end of each folder that adds tests).
function(npg_test_costs)
  get_property(tests DIRECTORY PROPERTY TESTS)
  set(costs ${NPG_TEST_COSTS})
  while(costs)
    list(POP_FRONT costs name cost)
    if(name IN_LIST tests)
      set_property(TEST ${name} PROPERTY COST ${cost})
      set_property(GLOBAL APPEND PROPERTY NPG_COSTED ${name})
    endif()
  endwhile()
endfunction()

# At the end of the top-level CMakeLists.txt: a name above that is no test (renamed, removed) is
# reported, not silently costless (a build without MPI reports mpi_train). The fuzz build adds no
# tests, the ThreadSanitizer build not mpi_train.
function(npg_test_costs_check)
  if(NPG_FUZZ OR NPG_TSAN)
    return()
  endif()
  get_property(costed GLOBAL PROPERTY NPG_COSTED)
  set(costs ${NPG_TEST_COSTS})
  while(costs)
    list(POP_FRONT costs name cost)
    if(NOT name IN_LIST costed)
      message(WARNING "cmake/test_costs.cmake: ${name} is not a test of this build")
    endif()
  endwhile()
endfunction()
