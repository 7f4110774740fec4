//! The real-time loop: board, DOB/RFOB observers, force and position control, experiments,
//! online features and the recorder. Filled in by the rt-loop issue.
