//! Composition: the system registry, schedule files (systems/*.ron) and scene files (scenes/*.ron).
