// The start-up peer of `ibmr --help` for bench_process_start: a program that links OpenCV's core
// and image codecs, as any OpenCV tool that reads images does, and exits at once (with an
// argument it reads that image, so the codecs are a real dependency the linker keeps).
#include <opencv2/imgcodecs.hpp>

int main(int argc, char** argv) { return argc > 1 && cv::imread(argv[1]).empty() ? 1 : 0; }
