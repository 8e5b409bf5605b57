//! placeholder
pub struct Homing; pub struct HomingMethod;
