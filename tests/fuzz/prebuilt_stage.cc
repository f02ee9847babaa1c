// The only source of a stage library in a fuzz build that links a gcc build's stage libraries
// instead of compiling them (IBMR_FUZZ_PREBUILT_STAGES, tests/fuzz/CMakeLists.txt): the stage's
// code comes from the prebuilt archive this empty library links.
