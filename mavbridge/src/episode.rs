//! One episode of the Plant API on a real vehicle: plant time from the vehicle's clock (its
//! epoch at the last reset or the first state), the samples' sequence, contacts, path length
//! and the watchdog's time. A vehicle is never teleported: what a reset changes is this book,
//! not the vehicle.

use mav::{AppliedCommand, CommandMeta, Contacts, PlantSample, Scenario, State};

/// The command a sample carries before the controller's first: level hover.
pub fn initial_command(scenario: &Scenario) -> AppliedCommand {
    AppliedCommand {
        input: scenario.model.hover_input(),
        meta: CommandMeta::default(),
        applied_time_ns: 0,
        saturated: false,
        initial: true,
    }
}

/// The book of one episode.
#[derive(Debug, Clone)]
pub struct Episode {
    pub scenario: Scenario,
    contacts: Contacts,
    path_length_m: f64,
    /// Vehicle time of plant time 0, ns (`None`: set by the next state).
    epoch_vehicle_ns: Option<u64>,
    next_seq: u64,
    current: Option<PlantSample>,
    pub last_command: AppliedCommand,
    watchdog_hover_ns: u64,
    flight_id: u64,
}

fn speed(x: &State) -> f64 {
    (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt()
}

impl Episode {
    pub fn new(scenario: Scenario, flight_id: u64) -> Self {
        Self {
            contacts: Contacts::new(scenario.obstacles.clone(), scenario.ground_z_m),
            path_length_m: 0.0,
            epoch_vehicle_ns: None,
            next_seq: 0,
            current: None,
            last_command: initial_command(&scenario),
            watchdog_hover_ns: 0,
            flight_id,
            scenario,
        }
    }

    /// A new episode starting at vehicle time `vehicle_ns` in `state`: its first sample.
    pub fn restart(
        &mut self,
        scenario: Scenario,
        flight_id: u64,
        vehicle_ns: u64,
        state: State,
    ) -> PlantSample {
        *self = Self::new(scenario, flight_id);
        self.epoch_vehicle_ns = Some(vehicle_ns);
        self.contacts.observe(0, &state);
        self.emit(0, state, false)
    }

    /// Plant time of a vehicle time, ns.
    pub fn plant_ns(&self, vehicle_ns: u64) -> u64 {
        vehicle_ns.saturating_sub(self.epoch_vehicle_ns.unwrap_or(vehicle_ns))
    }

    pub fn sample(&self) -> Option<&PlantSample> {
        self.current.as_ref()
    }

    /// The sample of `state` at vehicle time `vehicle_ns` (`None`: older than the newest one).
    pub fn produce(&mut self, vehicle_ns: u64, state: State, watchdog_hover: bool) -> Option<PlantSample> {
        let epoch = *self.epoch_vehicle_ns.get_or_insert(vehicle_ns);
        let time_ns = vehicle_ns.checked_sub(epoch)?;
        if let Some(prev) = &self.current {
            if time_ns < prev.time_ns {
                return None;
            }
            let dt_s = mav::ns_to_s(time_ns - prev.time_ns);
            self.path_length_m += 0.5 * (speed(&prev.state) + speed(&state)) * dt_s;
            if watchdog_hover && prev.watchdog_hover {
                self.watchdog_hover_ns += time_ns - prev.time_ns;
            }
        }
        self.contacts.observe(time_ns, &state);
        Some(self.emit(time_ns, state, watchdog_hover))
    }

    fn emit(&mut self, time_ns: u64, state: State, watchdog_hover: bool) -> PlantSample {
        let sample = PlantSample {
            seq: self.next_seq,
            time_ns,
            state,
            last_command: self.last_command,
            watchdog_hover,
            collided: self.contacts.collided(),
            min_clearance_m: self.contacts.min_clearance_m(),
            path_length_m: self.path_length_m,
            collisions: self.contacts.collisions().to_vec(),
            watchdog_hover_ns: self.watchdog_hover_ns,
            flight_id: self.flight_id,
        };
        self.next_seq += 1;
        self.current = Some(sample.clone());
        sample
    }
}
