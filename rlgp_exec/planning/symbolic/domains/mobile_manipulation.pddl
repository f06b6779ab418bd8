; Mobile manipulation for R-LGP and GNPP (HSR: one hand, PR2: two hands).
;
; This file is the single definition of the symbolic domain: rlgp_exec.planning.symbolic parses it
; into action schemas, grounds them for its own search, and writes it (or a grounded, reformulated
; copy) for Fast Downward. Base motion is implied between actions (no move action, as in R-LGP).
;
; Supports: a `surface` (a fixture's top, or a region with room for several objects) takes any
; number of objects (`place`); a `slot` (a region with room for one object, e.g. a Hanoi peg) and
; a `movable` (another object: towers) take one object, on top, if it is clear (`stack`). The
; static (stackable ?o ?s) says ?o fits on ?s (footprint no larger: the Hanoi rule).
; A drawer cabinet is a surface (its top) and a cabinet: `take_knob` grasps its knob,
; `open_drawer` / `close_drawer` move the drawer and let the knob go, `drop` puts a held object
; into the open drawer and `pick_from_drawer` takes one out.
; STRIPS + typing only (no negative preconditions, no conditional effects), so the heuristics of
; Fast Downward that do not support them (lmcut) still apply.
(define (domain mobile_manipulation)
  (:requirements :strips :typing)
  (:types
    manipulator support - object
    surface slot movable - support
    cabinet - surface)
  (:predicates
    (hand-empty ?m - manipulator)
    (holding ?m - manipulator ?o - movable)
    (on ?o - movable ?s - support)
    (clear ?s - support)
    (stackable ?o - movable ?s - support)
    (in ?o - movable ?c - cabinet)
    (open ?c - cabinet)
    (closed ?c - cabinet)
    (knob-free ?c - cabinet)
    (holding-knob ?m - manipulator ?c - cabinet))

  (:action pick
    :parameters (?m - manipulator ?o - movable ?s - support)
    :precondition (and (hand-empty ?m) (on ?o ?s) (clear ?o))
    :effect (and (holding ?m ?o) (clear ?s)
                 (not (hand-empty ?m)) (not (on ?o ?s)) (not (clear ?o))))

  (:action place
    :parameters (?m - manipulator ?o - movable ?s - surface)
    :precondition (and (holding ?m ?o))
    :effect (and (on ?o ?s) (clear ?o) (hand-empty ?m)
                 (not (holding ?m ?o))))

  (:action stack
    :parameters (?m - manipulator ?o - movable ?s - support)
    :precondition (and (holding ?m ?o) (clear ?s) (stackable ?o ?s))
    :effect (and (on ?o ?s) (clear ?o) (hand-empty ?m)
                 (not (holding ?m ?o)) (not (clear ?s))))

  (:action take_knob
    :parameters (?m - manipulator ?c - cabinet)
    :precondition (and (hand-empty ?m) (knob-free ?c))
    :effect (and (holding-knob ?m ?c)
                 (not (hand-empty ?m)) (not (knob-free ?c))))

  (:action open_drawer
    :parameters (?m - manipulator ?c - cabinet)
    :precondition (and (holding-knob ?m ?c) (closed ?c))
    :effect (and (open ?c) (hand-empty ?m) (knob-free ?c)
                 (not (closed ?c)) (not (holding-knob ?m ?c))))

  (:action close_drawer
    :parameters (?m - manipulator ?c - cabinet)
    :precondition (and (holding-knob ?m ?c) (open ?c))
    :effect (and (closed ?c) (hand-empty ?m) (knob-free ?c)
                 (not (open ?c)) (not (holding-knob ?m ?c))))

  (:action drop
    :parameters (?m - manipulator ?o - movable ?c - cabinet)
    :precondition (and (holding ?m ?o) (open ?c))
    :effect (and (in ?o ?c) (hand-empty ?m)
                 (not (holding ?m ?o))))

  (:action pick_from_drawer
    :parameters (?m - manipulator ?o - movable ?c - cabinet)
    :precondition (and (hand-empty ?m) (in ?o ?c) (open ?c))
    :effect (and (holding ?m ?o)
                 (not (hand-empty ?m)) (not (in ?o ?c))))
)
