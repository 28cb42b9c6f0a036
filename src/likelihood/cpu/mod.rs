//! CPU reference implementation of every likelihood stage.
