//! Tests of the crate's parts on real and rendered data that reach inside it (place
//! recognition on 7-Scenes, the stereo front-end on rendered pairs); the tests of the system as
//! a caller drives it are in `tests/`.

mod place_recognition_7scenes;
mod stereo_rendered;
