use super::*;

fn addr(s: &str) -> SocketAddr {
    s.parse().expect("an address")
}

fn peers(side: Side) -> Peers {
    let config = UdpConfig {
        listen: addr("127.0.0.1:0"),
        forward: addr("127.0.0.1:14580"),
        plant_side: side,
        max_held_bytes: 1000,
    };
    Peers::new(&config, addr("127.0.0.1:14540"))
}

#[test]
fn the_first_sender_on_the_listen_side_becomes_the_client_and_every_other_sender_is_refused_and_counted() {
    let mut p = peers(Side::Listen);
    assert_eq!(p.client, None);
    assert_eq!(p.from_client(addr("127.0.0.1:5000")), Ok(()));
    assert_eq!(p.client, Some(addr("127.0.0.1:5000")));
    assert_eq!(p.from_client(addr("127.0.0.1:5000")), Ok(()));
    // Another port of the same host, and another host: refused, the client unchanged.
    assert_eq!(p.from_client(addr("127.0.0.1:5001")), Err(Refusal::ForeignClient));
    assert_eq!(p.from_client(addr("10.0.0.7:5000")), Err(Refusal::ForeignClient));
    assert_eq!(p.client, Some(addr("127.0.0.1:5000")));
    assert_eq!(p.refused_foreign_client, 2);
    assert_eq!(p.refused(Refusal::ForeignClient), 2);
    assert_eq!((p.refused_foreign_forward, p.refused_no_client), (0, 0));
}

#[test]
fn the_forward_side_answers_go_to_the_client_only_from_the_forward_address_and_only_once_a_client_is_known() {
    let mut p = peers(Side::Listen);
    // Before any client: nowhere to send, counted.
    assert_eq!(p.from_forward(addr("127.0.0.1:14580")), Err(Refusal::NoClient));
    assert_eq!(p.refused_no_client, 1);
    p.from_client(addr("127.0.0.1:5000")).expect("learned");
    assert_eq!(p.from_forward(addr("127.0.0.1:14580")), Ok(addr("127.0.0.1:5000")));
    // Anyone but the forward address: refused, even the client itself.
    assert_eq!(p.from_forward(addr("127.0.0.1:14581")), Err(Refusal::ForeignForward));
    assert_eq!(p.from_forward(addr("127.0.0.1:5000")), Err(Refusal::ForeignForward));
    assert_eq!(p.refused_foreign_forward, 2);
    p.reset_counts();
    assert_eq!((p.refused_foreign_client, p.refused_foreign_forward, p.refused_no_client), (0, 0, 0));
    assert_eq!(p.client, Some(addr("127.0.0.1:5000")), "a reset of the counts keeps the client");
}

#[test]
fn the_plant_side_decides_which_direction_is_commands() {
    assert_eq!(Side::Listen.client_to_forward(), Direction::PlantToController);
    assert_eq!(Side::Listen.forward_to_client(), Direction::ControllerToPlant);
    assert_eq!(Side::Forward.client_to_forward(), Direction::ControllerToPlant);
    assert_eq!(Side::Forward.forward_to_client(), Direction::PlantToController);
}

#[test]
fn payload_seqs_count_the_datagrams_of_each_direction_from_zero() {
    let mut p = peers(Side::Listen);
    assert_eq!(p.take(Direction::ControllerToPlant), 0);
    assert_eq!(p.take(Direction::ControllerToPlant), 1);
    assert_eq!(p.take(Direction::PlantToController), 0);
}

#[test]
fn an_address_without_a_port_or_host_is_refused_naming_the_flag() {
    for bad in ["", "14540", ":14540", "127.0.0.1:", "127.0.0.1:99999"] {
        let e = parse_address("--udp-listen", bad).expect_err(bad);
        assert_eq!(e.flag, "--udp-listen");
        assert!(e.to_string().starts_with("--udp-listen"), "{e}");
    }
    assert_eq!(parse_address("--udp-listen", "[::1]:14540"), Ok(addr("[::1]:14540")));
}

#[test]
fn datagrams_past_the_held_bytes_cap_are_refused_and_counted_and_room_comes_back_at_release() {
    let mut p = peers(Side::Listen);
    assert!(p.hold(600));
    assert!(p.hold(400), "exactly at the cap");
    assert!(!p.hold(1), "past it");
    assert_eq!((p.held_bytes, p.dropped_held_cap), (1000, 1));
    p.release(600);
    assert!(p.hold(500));
    assert!(!p.hold(200));
    assert_eq!((p.held_bytes, p.dropped_held_cap), (900, 2));
    p.reset_counts();
    assert_eq!((p.held_bytes, p.dropped_held_cap), (900, 0), "held bytes are a state, not a count");
}
