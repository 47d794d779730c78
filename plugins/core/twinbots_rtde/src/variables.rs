//! The variables a recipe may name, with their types (RTDE guide, "Field names and associated
//! types", e-Series / PolyScope 5): what the controller sends (outputs) and what a client may set
//! (inputs). The general-purpose registers come in a lower range (0–23, for external clients
//! such as fieldbus adapters) and an upper range (24–47).

use std::sync::LazyLock;

use crate::types::DataType;

/// A named variable and its type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Variable {
    pub name: String,
    pub data_type: DataType,
}

/// Registers per kind (int, double): 0–47.
pub const REGISTERS: usize = 48;

use DataType::*;

const OUTPUTS: &[(&str, DataType)] = &[
    ("timestamp", Double),
    ("target_q", Vector6d),
    ("target_qd", Vector6d),
    ("target_qdd", Vector6d),
    ("target_current", Vector6d),
    ("target_moment", Vector6d),
    ("actual_q", Vector6d),
    ("actual_qd", Vector6d),
    ("actual_current", Vector6d),
    ("actual_current_window", Vector6d),
    ("joint_control_output", Vector6d),
    ("actual_TCP_pose", Vector6d),
    ("actual_TCP_speed", Vector6d),
    ("actual_TCP_force", Vector6d),
    ("target_TCP_pose", Vector6d),
    ("target_TCP_speed", Vector6d),
    ("actual_digital_input_bits", Uint64),
    ("joint_temperatures", Vector6d),
    ("actual_execution_time", Double),
    ("robot_mode", Int32),
    ("joint_mode", Vector6Int32),
    ("safety_mode", Int32),
    ("safety_status", Int32),
    ("actual_tool_accelerometer", Vector3d),
    ("speed_scaling", Double),
    ("target_speed_fraction", Double),
    ("actual_momentum", Double),
    ("actual_main_voltage", Double),
    ("actual_robot_voltage", Double),
    ("actual_robot_current", Double),
    ("actual_joint_voltage", Vector6d),
    ("actual_digital_output_bits", Uint64),
    ("runtime_state", Uint32),
    ("elbow_position", Vector3d),
    ("elbow_velocity", Vector3d),
    ("robot_status_bits", Uint32),
    ("safety_status_bits", Uint32),
    ("analog_io_types", Uint32),
    ("standard_analog_input0", Double),
    ("standard_analog_input1", Double),
    ("standard_analog_output0", Double),
    ("standard_analog_output1", Double),
    ("io_current", Double),
    ("euromap67_input_bits", Uint32),
    ("euromap67_output_bits", Uint32),
    ("euromap67_24V_voltage", Double),
    ("euromap67_24V_current", Double),
    ("tool_mode", Uint32),
    ("tool_analog_input_types", Uint32),
    ("tool_analog_input0", Double),
    ("tool_analog_input1", Double),
    ("tool_output_voltage", Int32),
    ("tool_output_current", Double),
    ("tool_temperature", Double),
    ("tool_force_scalar", Double),
    ("output_bit_registers0_to_31", Uint32),
    ("output_bit_registers32_to_63", Uint32),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("tool_output_mode", Uint8),
    ("tool_digital_output0_mode", Uint8),
    ("tool_digital_output1_mode", Uint8),
    ("payload", Double),
    ("payload_cog", Vector3d),
    ("payload_inertia", Vector6d),
    ("script_control_line", Uint32),
    ("ft_raw_wrench", Vector6d),
    ("joint_position_deviation_ratio", Double),
    ("collision_detection_ratio", Double),
    ("time_scale_source", Uint32),
];

const INPUTS: &[(&str, DataType)] = &[
    ("speed_slider_mask", Uint32),
    ("speed_slider_fraction", Double),
    ("standard_digital_output_mask", Uint8),
    ("standard_digital_output", Uint8),
    ("configurable_digital_output_mask", Uint8),
    ("configurable_digital_output", Uint8),
    ("tool_digital_output_mask", Uint8),
    ("tool_digital_output", Uint8),
    ("standard_analog_output_mask", Uint8),
    ("standard_analog_output_type", Uint8),
    ("standard_analog_output_0", Double),
    ("standard_analog_output_1", Double),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("external_force_torque", Vector6d),
];

/// Every output variable, in one fixed order (a controller's state is a value per entry).
pub fn outputs() -> &'static [Variable] {
    static TABLE: LazyLock<Vec<Variable>> = LazyLock::new(|| {
        let mut out = table(OUTPUTS);
        out.extend(registers("output"));
        // The input registers read back as outputs: what a client (or the program) last set.
        out.extend(registers("input"));
        out
    });
    &TABLE
}

/// Every input variable, in one fixed order.
pub fn inputs() -> &'static [Variable] {
    static TABLE: LazyLock<Vec<Variable>> = LazyLock::new(|| {
        let mut out = table(INPUTS);
        out.extend(registers("input"));
        out
    });
    &TABLE
}

/// The index of output `name` in [`outputs`].
pub fn output_index(name: &str) -> Option<usize> {
    outputs().iter().position(|v| v.name == name)
}

/// The index of input `name` in [`inputs`].
pub fn input_index(name: &str) -> Option<usize> {
    inputs().iter().position(|v| v.name == name)
}

fn table(entries: &[(&str, DataType)]) -> Vec<Variable> {
    entries.iter().map(|&(name, data_type)| Variable { name: name.to_string(), data_type }).collect()
}

/// `{side}_int_register_0..47` (INT32), `{side}_double_register_0..47` (DOUBLE) and
/// `{side}_bit_register_64..127` (BOOL).
fn registers(side: &str) -> Vec<Variable> {
    let ints = (0..REGISTERS).map(|i| Variable { name: format!("{side}_int_register_{i}"), data_type: Int32 });
    let doubles = (0..REGISTERS).map(|i| Variable { name: format!("{side}_double_register_{i}"), data_type: Double });
    let bits = (64..128).map(|i| Variable { name: format!("{side}_bit_register_{i}"), data_type: Bool });
    ints.chain(doubles).chain(bits).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_types_are_the_guides() {
        for table in [outputs(), inputs()] {
            let mut names: Vec<&str> = table.iter().map(|v| v.name.as_str()).collect();
            names.sort();
            let before = names.len();
            names.dedup();
            assert_eq!(names.len(), before, "a name appears twice");
        }
        let t = |name: &str| outputs()[output_index(name).unwrap()].data_type;
        assert_eq!(t("actual_q"), Vector6d);
        assert_eq!(t("actual_TCP_pose"), Vector6d);
        assert_eq!(t("robot_mode"), Int32);
        assert_eq!(t("joint_mode"), Vector6Int32);
        assert_eq!(t("output_int_register_47"), Int32);
        assert_eq!(t("input_double_register_24"), Double);
        assert_eq!(inputs()[input_index("input_bit_register_64").unwrap()].data_type, Bool);
        assert!(input_index("actual_q").is_none(), "an output is no input");
        assert!(output_index("output_int_register_48").is_none());
    }
}
