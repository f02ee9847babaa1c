// Exceptions that carry a message fit for a user: which file (and line or key), what is wrong,
// and what to do. The runner prints them and marks the stage failed; nothing already written
// is lost because every write is atomic.
#pragma once

#include <stdexcept>
#include <string>

namespace ibmr {

// A file could not be read, parsed or written.
class IoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A user's input or parameter is unusable (bad value, empty silhouette, no overlap, ...).
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace ibmr
