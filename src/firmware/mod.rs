//! STM32 firmware glue (issue 6): not built yet.
