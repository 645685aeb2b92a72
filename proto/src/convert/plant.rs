//! Conversions of the plant API messages (see the module above for the rules).
