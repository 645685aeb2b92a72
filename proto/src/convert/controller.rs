//! Conversions of the controller API messages (see the module above for the rules).
