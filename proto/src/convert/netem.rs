//! Conversions of the netem API messages (see the module above for the rules).
